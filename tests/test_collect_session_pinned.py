"""A lockstep `--sim` session is pinned bit for bit: the speed work on the bus layer, the simulated chain
and the plant must not change one recorded number for a given seed.

The digests below were computed with the code before that work (commit 74d912e) on x86_64 Linux
(numpy 2, pinocchio 3). They hash every /leader/* and /follower/* dataset (dtype, shape and bytes),
not /timing (wall clock). Floating-point results can differ in the last bits between platforms or
library builds (pinocchio's and numpy's vectorised kernels); there, the exact digest is not checked
(it is skipped with the reason), but the per-dataset sums below must still agree to 1e-9 relative.
"""

from __future__ import annotations

import hashlib
import platform

import h5py
import numpy as np
import pytest

from collect.runner import RunOptions, run_session

DURATION_S = 1.0
SEED = 3
PINNED_DIGEST = "2dcaab95ef7736147deca9b5f310944a5d7eb73cb454e74f9f709356c12e6250"
PINNED_SUMS = {  # dataset -> (sum, sum of |x|) ignoring NaN, as recorded when pinned
    'leader/current': (455.56763904588297, 464.19177913246676),
    'leader/dq': (-203.7849384434453, 213.7093514119656),
    'leader/dq_servo': (-246.30704639665782, 257.19434061832726),
    'leader/goal_current': (455.96845007222146, 456.09219007287174),
    'leader/q': (-709.4354347813513, 933.5285521604131),
    'leader/q_goal': (0.0, 0.0),
    'leader/t': (249.50000000000003, 249.50000000000003),
    'leader/tau': (1164.0313260000003, 1181.8326700000002),
    'leader/tau_dis': (1155.9501503217543, 1155.979566801856),
    'leader/tau_res': (149.72905666239967, 303.90745663623966),
    'follower/current': (333.1000109850429, 400.91491107596084),
    'follower/dq': (-201.56637596940527, 238.61461936505475),
    'follower/dq_servo': (-247.12239325419068, 284.3406325504184),
    'follower/goal_current': (333.25872016651556, 392.84760023793206),
    'follower/q': (-704.2429098143585, 934.4351348060536),
    'follower/q_goal': (0.0, 0.0),
    'follower/t': (249.50000000000003, 249.50000000000003),
    'follower/tau': (858.8766500000002, 1011.2178060000001),
    'follower/tau_dis': (907.1952348495834, 1004.9318324341439),
    'follower/tau_res': (-90.18360023196146, 268.62299219747365),
}
PINNED_PLATFORM = ("Linux", "x86_64")


def session_digest(path) -> tuple[str, dict[str, tuple[float, float]]]:
    """SHA-256 over every /leader and /follower dataset (name, dtype, shape, bytes) and their sums."""
    h = hashlib.sha256()
    sums = {}
    with h5py.File(path, "r") as f:
        for group in ("leader", "follower"):
            for name in sorted(f[group]):
                data = f[group][name][()]
                key = f"{group}/{name}"
                h.update(f"{key} {data.dtype.str} {data.shape}\n".encode())
                h.update(np.ascontiguousarray(data).tobytes())
                x = data.astype(np.float64)
                sums[key] = (float(np.nansum(x)), float(np.nansum(np.abs(x))))  # q_goal etc. hold NaN
    return h.hexdigest(), sums


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("pinned") / "s.h5"
    run_session(RunOptions(output=out, sim=True, seed=SEED, duration=DURATION_S, status=False))
    return session_digest(out)


def test_the_session_equals_the_pinned_numbers(recorded):
    _digest, sums = recorded
    assert sums.keys() == PINNED_SUMS.keys()
    for key, (total, total_abs) in PINNED_SUMS.items():
        got, got_abs = sums[key]
        assert got == pytest.approx(total, rel=1e-9, abs=1e-12), key
        assert got_abs == pytest.approx(total_abs, rel=1e-9, abs=1e-12), key


def test_the_session_equals_the_pinned_bytes(recorded):
    if (platform.system(), platform.machine()) != PINNED_PLATFORM:
        pytest.skip(f"the digest was pinned on {PINNED_PLATFORM}; float results may differ in the last bits "
                    "elsewhere (the sums are still checked)")
    digest, _sums = recorded
    assert digest == PINNED_DIGEST
