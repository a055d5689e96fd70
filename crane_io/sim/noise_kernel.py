"""The arm plant's sensor noise drawn in compiled code from the plant's own numpy Generator: the
same numbers, in the same order, from the same bit generator state as ArmPlant._noise draws them with
numpy's methods, so a session is the same bit for bit either way.

`draw(rngp, n, p, raw_signs, draws, flips, signs, z)` draws, as ArmPlant._noise does for n servos:
- when p > 0, `Generator.random(n)` (n `next_double`s) into flips, then the one-pulse error's sign into
  signs as +-RAD_PER_PULSE: as `Generator.integers(0, 2, n)` draws it (numpy's Lemire method for the range
  0..1 keeps the top bit of one `next_uint32` each: the bit generator's own 32-bit buffer is used and kept,
  as numpy uses it), or, with `raw_signs` (ArmPlant._position_noise's raw path for a PCG64 with no half
  kept and an even n), bits 31 and 63 of n / 2 `next_uint64`s, which leave the 32-bit buffer untouched;
- then `Generator.standard_normal(draws * n)` into z: numpy's 256-step ziggurat as numba ports it
  (numba.np.random.distributions.random_standard_normal, the same tables and operations).

`rngp` (uint64[4]): the bit generator's state address and its next_uint64, next_uint32 and next_double
functions, from `bit_generator.ctypes` (`rng_pointers`). The bit generator's lock is not taken: the plant's
generator is used by its own thread only. tests/test_sim_noise_kernel.py checks the streams against numpy's.
"""

from __future__ import annotations

import ctypes

import numpy as np

from crane_io.dynamixel.units import RAD_PER_PULSE


def rng_pointers(rng: np.random.Generator) -> np.ndarray:
    """`draw`'s rngp for the Generator `rng` (keep `rng` alive while they are used: RngPointers)."""
    c = rng.bit_generator.ctypes
    addr = [ctypes.cast(f, ctypes.c_void_p).value for f in (c.next_uint64, c.next_uint32, c.next_double)]
    return np.array([c.state_address, *addr], dtype=np.uint64)


class RngPointers:
    """A Generator with its `rng_pointers` (`.rng`, `.array`). A copy or an unpickled one points into the
    copied generator, never into the original's memory."""

    __slots__ = ("rng", "array")

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self.array = rng_pointers(rng)

    def __reduce__(self):  # (copy.deepcopy too: the pointers made anew for the copied generator)
        return RngPointers, (self.rng,)


def _intrinsics():
    """The numba intrinsic that makes numba's bit generator value from rngp (numba's own unboxing of a
    Generator object costs several microseconds a call: it reads the pointers from Python each time)."""
    from numba.core import cgutils, types
    from numba.extending import intrinsic

    bitgen_type = types.NumPyRandomBitGeneratorType("bit_generator")

    @intrinsic
    def bitgen_of(typingctx, state, f64, f32, fdbl):
        sig = bitgen_type(types.uint64, types.uint64, types.uint64, types.uint64)

        def codegen(context, builder, signature, args):
            bg = cgutils.create_struct_proxy(bitgen_type)(context, builder)
            uintp = context.get_value_type(types.uintp)
            bg.state_address = builder.zext(args[0], uintp) if uintp.width > 64 else args[0]
            bg.state = args[0]
            bg.fnptr_next_uint64 = args[1]
            bg.fnptr_next_uint32 = args[2]
            bg.fnptr_next_double = args[3]
            bg.bit_generator = args[0]
            return bg._getvalue()

        return sig, codegen

    return bitgen_of


def draw(rngp, n, p, raw_signs, draws, flips, signs, z):
    """See the module docstring. Returns False (nothing drawn) when an array is too short."""
    if (rngp.shape[0] < 4 or (raw_signs and n % 2 != 0) or flips.shape[0] < n or signs.shape[0] < n
            or z.shape[0] < draws * n):
        return False
    bg = noise_bitgen_of(rngp[0], rngp[1], rngp[2], rngp[3])
    if p > 0:
        for i in range(n):
            flips[i] = noise_next_double(bg)
        if raw_signs:  # ArmPlant._position_noise's raw path: bits 31 and 63 of n / 2 64-bit outputs
            for i in range(0, n - 1, 2):
                v = noise_next_uint64(bg)
                signs[i] = _PULSE if (v >> np.uint64(31)) & np.uint64(1) else -_PULSE
                signs[i + 1] = _PULSE if v >> np.uint64(63) else -_PULSE
        else:
            for i in range(n):
                signs[i] = _PULSE if noise_next_uint32(bg) >> np.uint32(31) else -_PULSE
    for i in range(draws * n):
        z[i] = noise_standard_normal(bg)
    return True


_PULSE = RAD_PER_PULSE
# the numba pieces `draw` calls (namespace() gives them; plain Python cannot call draw)
noise_bitgen_of = noise_next_double = noise_next_uint32 = noise_next_uint64 = noise_standard_normal = None
_NAMES = ("draw",)


def namespace() -> dict | None:
    """This module's functions with the numba pieces they call (for crane_io.jit.compile_functions), or
    None without numba."""
    try:
        from numba.np.random.distributions import random_standard_normal
        from numba.np.random.generator_core import next_double, next_uint32, next_uint64
    except ImportError:
        return None
    ns = dict(globals())
    ns.update(noise_bitgen_of=_intrinsics(), noise_next_double=next_double, noise_next_uint32=next_uint32,
              noise_next_uint64=next_uint64,
              noise_standard_normal=random_standard_normal)
    return ns


_F = "float64[::1]"
SIGNATURES = {"draw": (f"(uint64[::1], int64, float64, boolean, int64, {_F}, {_F}, {_F})",)}


def compiled():
    """The compiled `draw`, or None without numba."""
    global _COMPILED
    if _COMPILED is None:
        from crane_io.jit import compile_functions

        ns = namespace()
        fns = None if ns is None else compile_functions(ns, _NAMES, SIGNATURES,
                                                        qualname_prefix="noise_kernel.")
        _COMPILED = False if fns is None else fns["draw"]
    return _COMPILED or None


_COMPILED = None
_VERIFIED: bool | None = None


def _numpy_draw(rng: np.random.Generator, n: int, raw_signs: bool, draws: int):
    """What `draw` must give with p > 0, drawn with numpy's own methods (ArmPlant._noise's order)."""
    if raw_signs:
        raw = rng.bit_generator.random_raw(n + n // 2)
        flips = (raw[:n] >> np.uint64(11)) * 2.0 ** -53
        bits = np.stack([(raw[n:] >> np.uint64(31)) & np.uint64(1), raw[n:] >> np.uint64(63)], axis=1).ravel()
    else:
        flips = rng.random(n)
        bits = rng.integers(0, 2, n)
    signs = np.where(bits == 1, RAD_PER_PULSE, -RAD_PER_PULSE)
    return flips, signs, rng.standard_normal(draws * n)


def verified() -> bool:
    """Whether the compiled `draw` gives numpy's numbers and leaves numpy's state, checked once a process on
    seeded generators (both sign paths, enough normals to reach the ziggurat's rare branches). `draw` rests
    on numba's port of numpy's normal sampler: a numba whose port differs is caught here, and the plant then
    draws its noise with numpy (ArmPlant.kernel_cycle_args gives None), with a warning."""
    global _VERIFIED
    if _VERIFIED is None:
        fn = compiled()
        ok = fn is not None
        for seed, n, raw_signs, draws in ((7, 3, False, 2), (8, 4, True, 2), (9, 8, False, 4000)):
            if not ok:
                break
            mine, ref = np.random.default_rng(seed), np.random.default_rng(seed)
            flips, signs, z = np.zeros(n), np.zeros(n), np.zeros(draws * n)
            ok = bool(fn(rng_pointers(mine), n, 0.5, raw_signs, draws, flips, signs, z))
            f2, s2, z2 = _numpy_draw(ref, n, raw_signs, draws)
            ok = ok and (np.array_equal(flips, f2) and np.array_equal(signs, s2) and np.array_equal(z, z2)
                         and mine.bit_generator.state == ref.bit_generator.state)
        if fn is not None and not ok:
            import warnings

            warnings.warn("this numba's normal sampler differs from numpy's: the simulated arms draw their "
                          "sensor noise with numpy (a little slower, the same sessions)", stacklevel=2)
        _VERIFIED = ok
    return _VERIFIED
