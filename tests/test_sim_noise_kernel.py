"""crane_io.sim.noise_kernel: the sensor noise drawn in compiled code from the plant's numpy Generator gives
numpy's numbers in numpy's order and leaves the generator in numpy's state (sessions stay the same
bit for bit with the noise drawn inside the lockstep kernel)."""

from __future__ import annotations

import numpy as np
import pytest

from crane_io.dynamixel.units import RAD_PER_PULSE
from crane_io.sim import noise_kernel
from crane_io.sim.arm_plant import ArmPlant

draw = noise_kernel.compiled()
pytestmark = pytest.mark.skipif(draw is None, reason="numba is not installed")
SIGNS = np.array((-RAD_PER_PULSE, RAD_PER_PULSE))


def _numpy_draw(rng, n, p, raw_signs, draws):
    """What ArmPlant._noise draws, with numpy's methods."""
    flips = signs = np.zeros(0)
    if p > 0:
        if raw_signs:
            raw = rng.bit_generator.random_raw(n + n // 2)
            flips = (raw[:n] >> np.uint64(11)) * (1.0 / 9007199254740992.0)
            bits = np.stack([(raw[n:] >> np.uint64(31)) & np.uint64(1), raw[n:] >> np.uint64(63)], 1).ravel()
            signs = SIGNS.take(bits.astype(np.int64))
        else:
            flips = rng.random(n)
            signs = SIGNS.take(rng.integers(0, 2, size=n, dtype=np.int64))
    return flips, signs, rng.standard_normal(draws * n)


@pytest.mark.parametrize("n, p, raw_signs, draws, half_kept", [
    (8, 0.01, True, 2, False), (8, 0.01, False, 2, True), (7, 0.2, False, 2, False), (3, 0.5, False, 1, True),
    (8, 0.0, False, 2, False), (8, 0.01, True, 0, False)])
def test_draw_gives_numpys_numbers_and_leaves_its_state(n, p, raw_signs, draws, half_kept):
    mine, ref = np.random.default_rng(21), np.random.default_rng(21)
    if half_kept:  # a 32-bit draw leaves half of a 64-bit output in the bit generator
        assert mine.integers(0, 2**32, dtype=np.uint32) == ref.integers(0, 2**32, dtype=np.uint32)
    ptr = noise_kernel.rng_pointers(mine)
    flips, signs, z = np.full(n, -1.0), np.full(n, -1.0), np.full(2 * n, -1.0)
    for k in range(3000):  # ~90 000 normals: the ziggurat's rejection and tail branches too
        assert draw(ptr, n, p, raw_signs, draws, flips, signs, z)
        want = _numpy_draw(ref, n, p, raw_signs, draws)
        if p > 0:
            assert np.array_equal(flips, want[0]) and np.array_equal(signs, want[1]), k
        assert np.array_equal(z[:draws * n], want[2]), k
        assert mine.bit_generator.state == ref.bit_generator.state, k


def test_draw_refuses_arrays_too_short_and_an_odd_raw_draw():
    rng = np.random.default_rng(1)
    state = rng.bit_generator.state
    ptr = noise_kernel.rng_pointers(rng)
    assert not draw(ptr, 8, 0.1, False, 2, np.zeros(8), np.zeros(8), np.zeros(15))
    assert not draw(ptr, 8, 0.1, False, 2, np.zeros(7), np.zeros(8), np.zeros(16))
    assert not draw(ptr, 7, 0.1, True, 2, np.zeros(7), np.zeros(7), np.zeros(14))
    assert not draw(ptr[:3], 8, 0.1, False, 2, np.zeros(8), np.zeros(8), np.zeros(16))
    assert rng.bit_generator.state == state  # nothing drawn


def test_the_plants_cycle_arguments_draw_what_its_noise_draws():
    """ArmPlant.kernel_cycle_args' pointers and sign flag, drawn with `draw`, give ArmPlant._noise's numbers,
    also after a 32-bit draw from elsewhere and after the generator is replaced."""
    a, b = ArmPlant("crane-x7", seed=4), ArmPlant("crane-x7", seed=4)
    n = len(a.servo_ids)
    flips, signs, z = np.zeros(n), np.zeros(n), np.zeros(2 * n)
    for k in range(40):
        if k == 10:
            for plant in (a, b):
                plant.rng.integers(0, 7, dtype=np.int32)
        if k == 20:
            for plant in (a, b):
                plant.rng = np.random.default_rng(99)
        args = a.kernel_cycle_args(0.002)
        kt, ptr, p, raw_signs, vel_sd, cur_sd = args[11:17]
        assert draw(ptr, n, p, raw_signs, 2, flips, signs, z)
        p_b, raw, flips_b, signs_b, vel_b, cur_b, z_b = b._noise()
        assert (p, vel_sd, cur_sd) == (p_b, vel_b, cur_b)
        if raw.shape[0]:
            assert raw_signs
            flips_b = (raw[:n] >> np.uint64(11)) * (1.0 / 9007199254740992.0)
        else:
            assert not raw_signs
            assert np.array_equal(signs, signs_b)
        assert np.array_equal(flips, flips_b) and np.array_equal(z, z_b), k
        assert a.rng.bit_generator.state == b.rng.bit_generator.state, k


def test_copied_or_unpickled_pointers_point_into_their_own_generator():
    """RngPointers (ArmPlant keeps its generator's so) copied or unpickled with their generator point into
    the copy's state, not the original's: both then draw the same numbers, each advancing only its own."""
    import copy
    import pickle

    rng = np.random.default_rng(6)
    kept = noise_kernel.RngPointers(rng)
    for clone in (copy.deepcopy, lambda x: pickle.loads(pickle.dumps(x))):
        twin_rng, twin = clone((rng, kept))
        assert twin.rng is twin_rng and twin_rng is not rng
        state = rng.bit_generator.state
        out = []
        for k in (twin, kept):
            z = np.zeros(16)
            assert draw(k.array, 8, 0.0, False, 2, np.zeros(8), np.zeros(8), z)
            out.append(z)
        assert np.array_equal(out[0], out[1])
        assert twin_rng.bit_generator.state == rng.bit_generator.state != state


def test_the_compiled_sampler_is_checked_against_numpys_once_a_process():
    assert noise_kernel.verified()


def test_a_sampler_that_differs_from_numpys_leaves_the_noise_to_numpy(monkeypatch):
    """A numba whose normal sampler is not numpy's (simulated: every normal off by one ulp) is caught by the
    check, with a warning, and the plant's cycle arguments are then None (the chain draws with numpy)."""
    def off_by_an_ulp(rngp, n, p, raw_signs, draws, flips, signs, z):
        ok = draw(rngp, n, p, raw_signs, draws, flips, signs, z)
        z[: draws * n] = np.nextafter(z[: draws * n], np.inf)
        return ok

    monkeypatch.setattr(noise_kernel, "_COMPILED", off_by_an_ulp)
    monkeypatch.setattr(noise_kernel, "_VERIFIED", None)
    with pytest.warns(UserWarning, match="normal sampler differs"):
        assert not noise_kernel.verified()
    plant = ArmPlant("crane-x7", seed=4)
    assert plant.kernel_step_args(0.002) is not None and plant.kernel_cycle_args(0.002) is None
