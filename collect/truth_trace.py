"""The simulated arms' true external torques, one row per recorded cycle, in a file of its own
(`crane-collect run --sim --truth-trace PATH.h5`). Never written into the session: a model must not
learn from it; `crane-train fidelity SESSION --truth-trace PATH.h5` compares the observers with it.

Format "crane-truth-trace", version 1 (HDF5):

    attrs   format, format_version, joint_names (the session's order), session (its file name),
            sign (a sentence: world on the arm, positive pushes the joint positive)
    /t                (N,)   s     the session's follower/t, row for row
    /tau_ext          (N, J) N m   the follower plant's true external torque: contact with objects
                                   (plus the hand, when the hand is on the follower)
    /leader/tau_ext   (N, J) N m   the leader plant's true external torque: the simulated hand
    /in_contact       (N,)   bool  the follower touches an object

A row holds the torques acting when the cycle's angles were read (the end of the plant's last step):
what the observers estimate in that row, with the opposite sign (tau_res estimates -tau_ext). Rows are
written in blocks of `block` rows; the file is complete when `complete` is True.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from crane_io import session_format as sf
from crane_io.errors import ConfigError
from crane_io.output_files import write_error
from crane_io.session_format import TRUTH_TRACE_FORMAT as FORMAT
from crane_io.session_format import TRUTH_TRACE_VERSION as FORMAT_VERSION

from .session_detach import detach

# the datasets, in the order they are created and appended
_NAMES = (sf.TRUTH_TRACE_T, sf.TRUTH_TRACE_TAU_EXT, sf.TRUTH_TRACE_LEADER_TAU_EXT, sf.TRUTH_TRACE_IN_CONTACT)
SIGN = ("world on the arm: a positive value pushes the joint positive; a reaction-force observer's "
        "tau_res estimates -tau_ext")


class TruthTraceWriter:
    """`append(t, tau_ext_follower, tau_ext_leader, in_contact)` once per recorded row; `close()`."""

    def __init__(self, path: str | Path, joint_names, session: str, block: int = 1000):
        self.path = Path(path)
        if self.path.exists():
            self.path.unlink()
        try:
            self._f = h5py.File(self.path, "w")
        except OSError as exc:
            raise ConfigError(f"cannot create the truth trace {self.path} ({exc})") from None
        J = len(joint_names)
        f = self._f
        f.attrs.update({sf.FORMAT_ATTR: FORMAT, sf.VERSION_ATTR: FORMAT_VERSION, "session": str(session),
                        sf.JOINT_NAMES_ATTR: np.array([str(n) for n in joint_names],
                                                      dtype=h5py.string_dtype()),
                        "sign": SIGN, sf.COMPLETE_ATTR: False})
        opts = {"chunks": True, "compression": "gzip", "compression_opts": 1, "shuffle": True}
        t, ext, leader_ext, contact = _NAMES
        self._sets = {
            t: f.create_dataset(t, (0,), np.float64, maxshape=(None,), **opts),
            ext: f.create_dataset(ext, (0, J), np.float64, maxshape=(None, J), **opts),
            leader_ext: f.create_dataset(leader_ext, (0, J), np.float64, maxshape=(None, J), **opts),
            contact: f.create_dataset(contact, (0,), np.bool_, maxshape=(None,), **opts),
        }
        for name, unit in ((t, "s"), (ext, "N m"), (leader_ext, "N m")):
            self._sets[name].attrs["unit"] = unit
        self.block = int(block)
        self._rows: list[tuple] = []
        self.rows = 0
        self.closed = False
        self.failed = None  # the write failure that stopped the trace (CraneError)

    def append(self, t: float, tau_ext: np.ndarray, leader_tau_ext: np.ndarray, in_contact: bool) -> None:
        self._rows.append((float(t), np.array(tau_ext, dtype=float), np.array(leader_tau_ext, dtype=float),
                           bool(in_contact)))
        if len(self._rows) >= self.block:
            self._flush()

    def _flush(self) -> None:
        if self.failed is not None:
            raise self.failed
        try:
            if self._rows:
                t, fe, le, c = zip(*self._rows)
                n0, n = self.rows, len(t)
                for name, values in zip(_NAMES, (t, fe, le, c)):
                    ds = self._sets[name]
                    ds.resize(n0 + n, axis=0)
                    ds[n0:] = np.array(values)
                self.rows += n
                self._rows = []
            self._f.flush()
        except (OSError, RuntimeError) as exc:
            # a failed write (a full disk): HDF5 must not touch the file again (a close that fails half
            # way crashes the process later); the incomplete trace is removed
            detach(self._f)
            self.path.unlink(missing_ok=True)
            self.failed = write_error(exc, self.path, "truth trace")
            raise self.failed from None

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            if self.failed is None:
                self._flush()
                self._f.attrs[sf.COMPLETE_ATTR] = True
                self._flush()
        finally:
            try:
                self._f.close()
            except Exception:  # noqa: BLE001 - a detached file: its failure was raised already
                if self.failed is None:
                    raise
