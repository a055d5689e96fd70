"""Damaged bytes in a session file: every dataset carries a fletcher32 checksum, and crane-train names the
damaged dataset in one sentence (exit 2) instead of training on it."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from collect.recorder import SessionRecorder
from crane_io.errors import SessionDamagedError
from train.cli import main
from train.data.session import read_session

NAMES = [f"joint{i}" for i in range(1, 8)] + ["gripper"]


def _session(path, rows=600):
    rng = np.random.default_rng(1)
    with SessionRecorder(path, joint_names=NAMES, rate_hz=100, source="sim", lockstep=True) as rec:
        for k in range(rows):
            rec.append({"follower/t": k / 100, "follower/q": np.sin(k / 50 + np.arange(8)),
                        "follower/tau": rng.normal(size=8)})
    return path


def _flip(path, dataset: str, chunk: int = 1, nbytes: int = 8) -> None:
    """Flip `nbytes` bytes (64 bits) in the middle of one stored chunk of `dataset`."""
    import h5py

    with h5py.File(path, "r") as f:
        info = f[dataset].id.get_chunk_info(chunk)
    offset = info.byte_offset + info.size // 2
    with open(path, "r+b") as fh:
        fh.seek(offset)
        data = bytearray(fh.read(nbytes))
        fh.seek(offset)
        fh.write(bytes(b ^ 0xFF for b in data))


@pytest.mark.parametrize("dataset", ["/follower/q", "/follower/tau", "/follower/t"])
def test_flipped_bits_name_the_damaged_dataset(tmp_path, dataset):
    p = _session(tmp_path / "s.h5")
    assert len(read_session(p)) == 600
    _flip(p, dataset)
    with pytest.raises(SessionDamagedError) as err:
        read_session(p)
    assert f"dataset {dataset} fails its fletcher32 checksum in rows 50-99," in str(err.value)
    result = CliRunner().invoke(main, ["info", str(p)])
    assert result.exit_code == 2
    assert result.output.startswith("Error: ") and result.output.count("\n") == 1, result.output
    assert str(p) in result.output and dataset in result.output and "Traceback" not in result.output


def test_the_checksum_is_recomputed_as_hdf5_does(tmp_path):
    """Every intact chunk of a recorded file passes the recomputed fletcher32 (so a failure found by it
    is real), and a flip in one chunk is found in that chunk only."""
    import h5py

    from crane_io.h5check import bad_checksum_rows

    p = _session(tmp_path / "s.h5")
    with h5py.File(p, "r") as f:
        assert all(not bad_checksum_rows(f[n]) for n in ("follower/t", "follower/q", "follower/tau",
                                                            "leader/q", "timing/overrun", "events"))
    _flip(p, "/follower/tau", chunk=3, nbytes=1)
    with h5py.File(p, "r") as f:
        assert bad_checksum_rows(f["follower/tau"]) == [(150, 199)]
        assert not bad_checksum_rows(f["follower/q"])
