"""The loop's recorded torques and tracking error (collect/bilateral_loop.py `record_numbers`, compiled)
against its numpy path: the same numbers bit for bit, and arrays of another kind taken by the numpy path
(the compiled call is never compiled anew for them)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from collect import bilateral_loop as bl

KERNEL = bl._record_kernel()


def _numpy(ql, qf, err_sq, bil, sent_l, cur_l, sent_f, cur_f, kt):
    e = ql - qf
    err_sq += e * e
    return np.where(bil, sent_l, cur_l) * kt, np.where(bil, sent_f, cur_f) * kt


def _args(rng, n):
    a = [rng.normal(0, 2, n) for _ in range(2)]
    a[0][rng.integers(n)] = -0.0
    return (a[0], a[1], rng.uniform(0, 1, n), rng.random(n) < 0.5, rng.normal(0, 1, n), rng.normal(0, 1, n),
            rng.normal(0, 1, n), rng.normal(0, 1, n), rng.uniform(0.5, 3, n))


@pytest.mark.skipif(KERNEL is None, reason="numba is not installed")
@pytest.mark.parametrize("n", [3, 7, 8])
def test_the_compiled_row_numbers_are_the_numpy_ones(n):
    rng = np.random.default_rng(n)
    for _ in range(50):
        args = _args(rng, n)
        args[4][rng.integers(n)] = np.nan  # a value that is not finite passes through as it is
        err_a, err_b = args[2].copy(), args[2].copy()
        out = np.empty((2, n))
        KERNEL(*args[:2], err_a, *args[3:], out)
        tl, tf = _numpy(*args[:2], err_b, *args[3:])
        assert err_a.tobytes() == err_b.tobytes()
        assert out[0].tobytes() == tl.tobytes() and out[1].tobytes() == tf.tobytes()


@pytest.mark.skipif(KERNEL is None, reason="numba is not installed")
def test_arrays_of_another_kind_are_refused_not_compiled():
    rng = np.random.default_rng(0)
    args = list(_args(rng, 8))
    before = len(KERNEL.signatures)
    for bad in (args[0].astype(np.float32), np.repeat(args[0], 2)[::2]):  # float32; not contiguous
        with pytest.raises(TypeError):
            KERNEL(bad, *args[1:], np.empty((2, 8)))
    assert len(KERNEL.signatures) == before


@pytest.mark.parametrize("kind", ["float64", "float32", "strided"])
def test_the_loop_records_the_same_row_whatever_arrays_it_is_given(kind):
    """`BilateralLoop._record` with the compiled call and with the numpy path (arrays it refuses)."""
    rng = np.random.default_rng(1)
    args = _args(rng, 8)
    rows = []
    for numbers in (KERNEL, None):
        loop = SimpleNamespace(timer=SimpleNamespace(last={"bus_leader": 0.0, "bus_follower": 0.0,
                                                           "compute": 0.0},
                                                     now=lambda: 0.0, last_period=0.0, last_overrun=False,
                                                     add=lambda *a: None),
                               kt=args[8], bil=args[3], err_sq=args[2].copy(), _numbers=numbers,
                               ctl=SimpleNamespace(leader=SimpleNamespace(dq=0, tau_dis=0, tau_res=0),
                                                   follower=SimpleNamespace(dq=0, tau_dis=0, tau_res=0)),
                               q_goal_row=None, lockstep=True, truth_trace=None, view=None)
        got = []
        loop.recorder = object()
        loop._columns = (loop.recorder, got.append)

        def state(q, cur):
            if kind == "float32":
                q = q.astype(np.float32)
            elif kind == "strided":
                q = np.repeat(q, 2)[::2]
            return SimpleNamespace(position=q, current=cur, velocity=cur)

        sl, sf = state(args[0], args[5]), state(args[1], args[7])
        bl.BilateralLoop._record(loop, 0.5, sl, sf, args[4], args[6])
        rows.append((loop.err_sq.tobytes(), got[0][2].tobytes(), got[0][12].tobytes()))
    assert rows[0] == rows[1]
