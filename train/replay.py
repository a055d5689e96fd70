"""`crane-train view`: a recorded session replayed in rerun, with the entities of the live view
(crane_io/view.py) on the session's own time axis (`/follower/t`).

Every sample (or every `every`-th: default 10, 50 a second of a 500 Hz session) of what the file holds:
both arms' q, tau, tau_dis, tau_res (a member or an arm the file lacks is left out: a session imported
from another rig may have only the follower's t, q and tau), the tracking error (leader q - follower q on
the bilateral joints, when both arms are there), the loop period from `/timing/period` (the period at the
sample and the longest since the previous one) and the arms in 3D. The file is only read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from crane_io.h5check import member

from .data.session import _open, read_session
from .data.session_check import dataset, read_rows

SIGNALS = ("q", "tau", "tau_dis", "tau_res")


@dataclass
class ReplayData:
    t: np.ndarray  # (M,) s, the kept samples
    data: dict = field(default_factory=dict)  # entity key -> (M, .) array (crane_io.view.SessionView keys)
    joint_names: tuple[str, ...] = ()
    bilateral_joints: tuple[str, ...] = ()
    arms: tuple[str, ...] = ()
    rows: int = 0  # samples in the file


def read_replay(path: Path | str, every: int = 10) -> ReplayData:
    """What the view shows of session `path`, every `every`-th sample. SessionFileError (one sentence) for
    a file that is not a readable session (train.data.session.read_session checks the required part)."""
    path = Path(path)
    every = max(int(every), 1)
    follower = read_session(path, "follower")
    names = follower.joint_names
    n = len(follower)
    bil = follower.attrs.get("bilateral_joints")
    bil = tuple(bil) if isinstance(bil, list) else ((bil,) if isinstance(bil, str) else names)
    bil = tuple(b for b in bil if b in names)
    raw: dict[str, np.ndarray] = {"follower/q": follower.q, "follower/tau": follower.tau}
    period = None
    with _open(path) as f:
        for arm in ("leader", "follower"):
            if member(path, f, arm, h5py.Group) is None:
                continue
            for sig in SIGNALS:
                key = f"{arm}/{sig}"
                ds = None if key in raw else dataset(path, f, key, len(names), required=False)
                if ds is not None:
                    raw[key] = read_rows(path, ds, min(n, ds.shape[0]))
        if member(path, f, "timing", h5py.Group) is not None:
            ds = dataset(path, f, "timing/period", required=False)
            period = None if ds is None else read_rows(path, ds, min(n, ds.shape[0]))
    m = min([n] + [len(a) for a in raw.values()] + ([len(period)] if period is not None else []))
    idx = np.arange(0, m, every)
    data = {key: arr[idx] for key, arr in raw.items()}
    arms = tuple(a for a in ("leader", "follower") if f"{a}/q" in data)
    if "leader/q" in data and bil:
        cols = [names.index(b) for b in bil]
        data["loop/tracking_error"] = data["leader/q"][:, cols] - data["follower/q"][:, cols]
    if period is not None:
        p = np.where(np.isfinite(period[:m]), period[:m], 0.0)
        data["loop/period"] = np.column_stack([p[idx], np.maximum.reduceat(p, idx)])
    return ReplayData(follower.t[idx], data, names, bil, arms, n)


def replay_session(path: Path | str, *, save: Path | str | None = None, every: int = 10) -> ReplayData:
    """Replay session `path` into a spawned rerun viewer, or into the .rrd file `save`. Raises
    ViewUnavailableError without rerun, SessionFileError for a bad session, ViewError when the file or
    viewer cannot be opened."""
    from crane_io.view import SessionView, import_rerun

    import_rerun()  # before the session is read: without rerun nothing else is worth doing
    rep = read_replay(path, every)

    def show(target) -> None:
        view = SessionView(rep.joint_names, rep.bilateral_joints, save=target, spawn=target is None,
                           recording_name=Path(path).name, arms=rep.arms)
        view.open()
        try:
            view.log_columns(rep.t, rep.data)
        finally:
            view.close()

    if save is None:
        show(None)
    else:  # the .rrd file whole or not at all (crane_io.output_files; a full disk is one sentence)
        from crane_io.output_files import atomic_path

        with atomic_path(save, "rerun file") as tmp:
            show(tmp)
    return rep
