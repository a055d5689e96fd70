"""Damaged or foreign input to `crane-train import`: one sentence (a CraneError), never another exception,
the input's bytes unchanged (train.data.importer.read_columns)."""

from __future__ import annotations

import hashlib
import io
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from crane_io.errors import CraneError
from train.data.importer import ImportMapError, read_columns

FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
CSV = b"t,q1,tau1\n" + b"".join(f"{i * 0.002},{0.1 * i},{-0.2 * i}\n".encode() for i in range(20))


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


NPZ = _npz(t=np.arange(20) * 0.002, q=np.ones((20, 2)), tau1=np.zeros(20))


def _write(content: bytes, suffix: str, folder: Path) -> Path:
    path = folder / f"in{suffix}"
    path.write_bytes(content)
    return path


def _columns(path: Path):
    return read_columns(path, ["t", "q[0]" if path.suffix == ".npz" else "q1", "tau1"])


def _read(content: bytes, suffix: str):
    with tempfile.TemporaryDirectory(prefix="import-input-") as folder:
        path = _write(content, suffix, Path(folder))
        before = hashlib.sha256(content).hexdigest()
        try:
            _columns(path)
            message = None
        except CraneError as exc:
            message = str(exc)
            assert message and "\n" not in message, message
        assert hashlib.sha256(path.read_bytes()).hexdigest() == before
    return message


@FUZZ
@given(data=st.data(), suffix=st.sampled_from([".csv", ".npz"]))
def test_flipped_cut_or_inserted_bytes_are_one_sentence(data, suffix):
    raw = bytearray(CSV if suffix == ".csv" else NPZ)
    action = data.draw(st.sampled_from(["cut", "flip", "insert"]), "action")
    at = data.draw(st.integers(0, len(raw) - 1), "at")
    if action == "cut":
        raw = raw[:at]
    elif action == "flip":
        raw[at] ^= 1 << data.draw(st.integers(0, 7), "bit")
    else:
        raw[at:at] = data.draw(st.binary(min_size=1, max_size=8), "bytes")
    _read(bytes(raw), suffix)


def _zip_flag_offsets(raw: bytes) -> list[int]:
    """Where the general-purpose flag bits of every local (PK 3 4, +6) and central (PK 1 2, +8) header
    of a ZIP archive are."""
    out = []
    for signature, offset in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        at = raw.find(signature)
        while at >= 0:
            out += [at + offset, at + offset + 1]
            at = raw.find(signature, at + 1)
    return out


def test_every_flag_bit_of_an_npz_header_flipped_is_one_sentence():
    """A flipped flag bit can mark a member encrypted or compressed in a way zipfile does not read
    (zipfile raises RuntimeError or NotImplementedError for those)."""
    offsets = _zip_flag_offsets(NPZ)
    assert len(offsets) == 12  # three members, each in a local and a central header
    refused = []
    for at in offsets:
        for bit in range(8):
            raw = bytearray(NPZ)
            raw[at] ^= 1 << bit
            refused.append(_read(bytes(raw), ".npz"))
    assert any(m and "encrypted" in m for m in refused)


@pytest.mark.parametrize("content, suffix, words", [
    (_npz(t=np.array([None, 1], dtype=object), q=np.ones((2, 2)), tau1=np.ones(2)), ".npz", "Python objects"),
    (b"PK\x03\x04" + bytes(range(200)), ".npz", "cannot be read as NPZ"),
    (b"t,q1,tau1\n1," + b"9" * 200000 + b",2\n", ".csv", "not a readable CSV"),
    (_npz(t=np.array(["a", "b"]), q=np.ones((2, 2)), tau1=np.ones(2)), ".npz", "not numbers"),
])
def test_foreign_input_is_refused_in_one_sentence(content, suffix, words, tmp_path):
    with pytest.raises(ImportMapError, match=words):
        _columns(_write(content, suffix, tmp_path))


def test_a_rate_that_disagrees_with_the_time_column_is_refused_at_import():
    from train.data.importer import convert, parse_map

    n = 200
    columns = {"t": np.arange(n) * 0.002, "q1": np.zeros(n), "tau1": np.zeros(n)}
    spec = parse_map(["t=t", "joint1.q=q1", "joint1.tau=tau1"])
    assert convert(columns, spec, rate_hz=500.0).rate_hz == 500.0
    with pytest.raises(ImportMapError, match="disagrees with the time column 't'"):
        convert(columns, spec, rate_hz=50.0)
