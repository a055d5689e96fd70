"""crane_io.output_files: outputs never replace inputs, never overwrite without force, and are written
atomically (a failed write leaves the old file and no temporary file)."""

from __future__ import annotations

import errno
import os

import pytest

from crane_io.output_files import (
    DiskFullError,
    OutputPathError,
    atomic_directory,
    atomic_path,
    check_output,
    write_text_atomic,
)


def test_output_equal_to_an_input_is_refused_through_links(tmp_path):
    src = tmp_path / "s.h5"
    src.write_bytes(b"data")
    (tmp_path / "link.h5").symlink_to(src)
    os.link(src, tmp_path / "hard.h5")
    for out in (src, tmp_path / "link.h5", tmp_path / "hard.h5", tmp_path / "sub" / ".." / "s.h5"):
        (tmp_path / "sub").mkdir(exist_ok=True)
        with pytest.raises(OutputPathError, match="same file as the input"):
            check_output(out, inputs=[src], force=True)
    assert src.read_bytes() == b"data"


def test_existing_output_needs_force_and_missing_folder_is_refused(tmp_path):
    out = tmp_path / "r.html"
    out.write_text("old")
    with pytest.raises(OutputPathError, match="`force`"):
        check_output(out)
    assert check_output(out, force=True) == out
    with pytest.raises(OutputPathError, match="does not exist"):
        check_output(tmp_path / "nope" / "r.html")
    with pytest.raises(OutputPathError, match="empty"):
        check_output("")


def test_output_inside_an_input_folder_and_folder_holding_an_input(tmp_path):
    model = tmp_path / "model"
    model.mkdir()
    with pytest.raises(OutputPathError, match="inside the input"):
        check_output(model / "x.json", inputs=[model])
    with pytest.raises(OutputPathError, match="holds the input"):
        check_output(tmp_path, inputs=[model / "model.json"], force=True, directory=True)


def test_two_outputs_of_one_command_are_refused(tmp_path):
    with pytest.raises(OutputPathError, match="another output"):
        check_output(tmp_path / "a", others=[tmp_path / "a"])


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    out = tmp_path / "f.txt"
    out.write_text("good")
    with pytest.raises(RuntimeError), atomic_path(out) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert out.read_text() == "good"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.txt"]
    write_text_atomic(out, "new")
    assert out.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.txt"]


def test_a_full_disk_is_one_sentence_with_exit_3(tmp_path):
    out = tmp_path / "f.txt"
    with pytest.raises(DiskFullError, match="is full") as info, atomic_path(out):
        raise OSError(errno.ENOSPC, "No space left on device")
    assert info.value.exit_code == 3
    assert list(tmp_path.iterdir()) == []


def test_atomic_directory_replaces_a_folder_whole_or_not_at_all(tmp_path):
    target = tmp_path / "m"
    target.mkdir()
    (target / "model.json").write_text("old")
    with pytest.raises(ValueError), atomic_directory(target) as tmp:
        (tmp / "model.json").write_text("half")
        raise ValueError
    assert (target / "model.json").read_text() == "old"
    with atomic_directory(target) as tmp:
        (tmp / "model.json").write_text("new")
    assert (target / "model.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m"]


def test_missing_folders_are_allowed_only_when_the_writer_makes_them(tmp_path):
    out = tmp_path / "a" / "b" / "r.html"
    with pytest.raises(OutputPathError, match="does not exist"):
        check_output(out)
    assert check_output(out, make_folders=True) == out and not (tmp_path / "a").exists()
    write_text_atomic(out, "page")
    assert out.read_text() == "page"
    (tmp_path / "notes").write_text("a file")
    with pytest.raises(OutputPathError, match="notes is a file, not a folder"):
        check_output(tmp_path / "notes" / "x" / "r.html", make_folders=True)


def test_a_new_output_gets_the_usual_permissions_and_a_replaced_one_keeps_its_own(tmp_path):
    umask = os.umask(0o022)
    try:
        fresh = write_text_atomic(tmp_path / "new.txt", "x")
        assert fresh.stat().st_mode & 0o777 == 0o644  # not the temporary file's private 0o600
        old = tmp_path / "old.txt"
        old.write_text("x")
        old.chmod(0o640)
        write_text_atomic(old, "y")
        assert old.stat().st_mode & 0o777 == 0o640
        with atomic_directory(tmp_path / "m") as tmp:
            (tmp / "f").write_text("z")
        assert (tmp_path / "m").stat().st_mode & 0o777 == 0o755
    finally:
        os.umask(umask)


def test_the_temporary_file_keeps_the_targets_suffix_for_writers_that_read_it(tmp_path):
    with atomic_path(tmp_path / "plot.png") as tmp:
        assert tmp.suffix == ".png" and tmp.parent == tmp_path and tmp.name.startswith(".plot.png.")
        tmp.write_bytes(b"png")
    assert (tmp_path / "plot.png").read_bytes() == b"png"
