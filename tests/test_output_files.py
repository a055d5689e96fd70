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
