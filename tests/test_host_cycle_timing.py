"""The loop's timing sections: each bus's read and write of a cycle counted together, so the summary's
`bus_*_max_s` is the longest cycle on that bus (as the README says), the largest value of the rows'
/timing/bus_time_*."""

from __future__ import annotations

import h5py
import numpy as np

from collect.pacing import CycleTimer
from collect.runner import RunOptions, run_session


def test_add_cycle_is_three_adds():
    a, b = CycleTimer(500.0, lockstep=True), CycleTimer(500.0, lockstep=True)
    for t in (a, b):
        t.start()
    for bl, bf, c in [(1e-4, 2e-4, 3e-5), (5e-4, 1e-4, 2e-5), (2e-4, 3e-4, 9e-5)]:
        a.add_cycle(bl, bf, c)
        b.add("bus_leader", bl)
        b.add("bus_follower", bf)
        b.add("compute", c)
        assert a.last == b.last
        a.wait()
        b.wait()
    sa, sb = a.summary(), b.summary()
    for key in ("bus_leader", "bus_follower", "compute"):
        assert sa[f"{key}_mean_s"] == sb[f"{key}_mean_s"] and sa[f"{key}_max_s"] == sb[f"{key}_max_s"]
    assert sa["bus_leader_max_s"] == 5e-4


def test_the_bus_maxima_are_those_of_whole_cycles(tmp_path):
    p = tmp_path / "s.h5"
    run_session(RunOptions(output=p, sim=True, seed=2, duration=0.4, status=False))
    with h5py.File(p, "r") as f:
        timing = f["timing"]
        for arm in ("leader", "follower"):
            rows = timing[f"bus_time_{arm}"][()].astype(float)
            assert rows.size == 200 and np.all(rows > 0)
            top = timing.attrs[f"bus_{arm}_max_s"]
            # the rows are float32: the longest row is the longest cycle (read and write together)
            assert abs(rows.max() - top) <= 1e-6 * top, (rows.max(), top)
