"""The plant's two steppers (crane_io/sim/plant_backend.py): the compiled one (crane_io/sim/plant_kernel.py)
against the reference (crane_io/sim/plant_reference.py), through the plant that picked them.

Both take the rigid body from crane_io/sim/plant_rigid.py (checked against pinocchio in
tests/test_plant_rigid.py) and the effects from crane_io/sim/plant_layout.py, in the same order of operations.
What is pinned:
- the compiled code computes exactly what its Python source computes (no fused multiply-add, no
  reassociation), bit for bit;
- a plant's trajectory on the kernel is the reference stepper's (`ArmPlant(kernel=False)`) bit for bit,
  stick-slip included, for 3 and 7 joints;
- the reference stepper records the pinned 1 s session bit for bit, and so does the kernel; the kernel's
  trajectories are pinned; the plant's physics tests run on the kernel.
"""

from __future__ import annotations

import platform

import numpy as np
import pytest

from crane_io.errors import ConfigError
from crane_io.sim import plant_backend, plant_kernel, plant_rigid
from crane_io.sim.arm_plant import ArmPlant
from crane_io.sim.plant_api import ActuatorCommand

pytestmark = pytest.mark.skipif(plant_kernel.compiled() is None, reason="numba is not installed")

PERIOD = 0.002
STEPS = 600  # current mode with moving, stopping and sticking joints, then position mode from step 300
GAINS = np.tile([800.0, 0.0, 0.0], (8, 1))
EXTRA = {  # extra plant configurations (TOML), beside presets
    "locked-elsewhere": 'base = "crane-x7"\n[locked]\njoint3 = 0.4\njoint5 = -0.7\njoint6 = 0.3\n'
                        'joint7 = 1.1\n',
    "asymmetric+spring": 'base = "crane-x7"\n'  # (its [[effects]] replace the preset's)
                         '[[effects]]\neffect = "stiction"\njoint = "joint1"\ncoulomb = 0.3\n'
                         'breakaway = 0.4\n[[effects]]\neffect = "spring"\njoint = "joint1"\n'
                         'stiffness = 0.3\nrest_angle = 0.5\n'
                         '[[effects]]\neffect = "coulomb-asym"\njoint = "joint2"\ncoulomb_pos = 0.5\n'
                         'coulomb_neg = 0.3\n[[effects]]\neffect = "stiction"\njoint = "joint4"\n'
                         'coulomb = 0.25\nbreakaway = 0.3\n',
}


def _plant(tmp_path, name: str, **kw) -> ArmPlant:
    if name in EXTRA:
        path = tmp_path / f"{name}.toml"
        path.write_text(EXTRA[name])
        name = path
    return ArmPlant(name, **kw)


def _drive(k: int, n_int: int, rng: np.random.Generator):
    """Current mode with a varying current (move, stop, stick), then position mode: the command of step k."""
    mode = np.zeros(8, int) if k < 300 else np.full(8, 3)
    current = 0.6 * np.sin(0.013 * k + np.arange(8)) + 0.15 * np.sin(0.11 * k)
    position = 0.3 * np.sin(0.01 * k + np.arange(8))
    ext = np.zeros(8)
    ext[:n_int] = rng.normal(0, 0.05, n_int)
    return ActuatorCommand(np.ones(8, bool), mode, current, position, GAINS, np.full(8, 2.0)), ext


@pytest.mark.parametrize("name", ["crane-x7", "crane-x7-7dof", "hidden-cogging", "asymmetric+spring"])
def test_the_compiled_kernel_computes_what_its_python_source_computes_bit_for_bit(tmp_path, name):
    plant = _plant(tmp_path, name)
    stepper = plant._stepper
    compiled = stepper.step_substeps
    rng = np.random.default_rng(9)
    n = len(plant.joints)
    q, dq = plant.q.copy(), np.zeros(n)
    stuck = moving = 0
    for k in range(60):
        cmd = np.zeros((n, plant_kernel.CMD_COLS))
        cmd[:, plant_kernel.C_TAU] = rng.normal(0, 0.4, n)
        cmd[:, plant_kernel.C_EXT] = rng.normal(0, 0.05, n)
        if k % 3 == 2:  # some joints in a position mode
            pd = rng.random(n) < 0.5
            cmd[pd, plant_kernel.C_PD] = 1.0
            cmd[pd, plant_kernel.C_KP:plant_kernel.C_GOAL + 1] = (8.0, 0.2, -1.5, 1.5, 0.3)
        args = (cmd, plant.h, 8, stepper.geo, stepper.arm, stepper.par, stepper.cog, stepper.scal)
        got, want = compiled(q, dq, *args), plant_kernel.step(q, dq, *args)
        assert got.tobytes() == want.tobytes(), k
        q, dq = got[:n], got[n:2 * n]
        stuck, moving = stuck + int(np.any(dq == 0.0)), moving + int(np.any(dq != 0.0))
    assert stuck > 5 and moving > 5  # it went through sticking and moving joints


@pytest.mark.parametrize("name", ["crane-x7", "crane-x7-7dof", "baseline", "hidden-cogging", "hidden-offset",
                                  "hidden-stribeck", "asymmetric+spring", "locked-elsewhere"])
def test_the_kernel_gives_the_reference_paths_bits(tmp_path, name):
    fast, ref = _plant(tmp_path, name, seed=4), _plant(tmp_path, name, seed=4, kernel=False)
    assert fast.kernel and not ref.kernel
    rng = np.random.default_rng(2)
    n_int = len(fast.joints)
    stuck = 0
    for k in range(STEPS):
        cmd, ext = _drive(k, n_int, rng)
        for p in (fast, ref):
            p.set_external_torque(ext)
            p.step(cmd, PERIOD)
        for a, b in zip((*fast.state(), fast.motor_torque, fast._held_current),
                        (*ref.state(), ref.motor_torque, ref._held_current)):
            assert a.tobytes() == b.tobytes(), f"step {k}"
        stuck += int(np.any(fast.dq == 0.0))
        ra, rb = fast.read(), ref.read()  # the same noise stream
        assert ra.position.tobytes() == rb.position.tobytes()
    assert stuck > 20  # stick-slip was exercised


def test_the_kernel_is_the_default_where_it_applies(tmp_path, monkeypatch):
    assert ArmPlant("crane-x7").kernel and ArmPlant("crane-x7-7dof").kernel
    for name in ("contact-wall", "contact-table"):  # [[environment]] objects: the reference path
        assert not ArmPlant(name).kernel
        with pytest.raises(ConfigError, match="kernel=False"):
            ArmPlant(name, kernel=True)
    backlash = tmp_path / "backlash.toml"
    backlash.write_text('base = "baseline"\n[hidden]\neffect = "backlash"\njoint = "joint2"\nwidth = 0.0044\n'
                        'motor_inertia = 0.01\n')
    assert not ArmPlant(backlash).kernel
    monkeypatch.setenv("CRANE_PLANT_KERNEL", "0")
    assert not ArmPlant("crane-x7").kernel
    assert ArmPlant("crane-x7", kernel=True).kernel  # an explicit choice wins over the environment


def test_without_numba_the_reference_path_runs_the_rigid_bodys_python_source_to_the_same_bits(monkeypatch):
    """CRANE_PLANT_KERNEL=0: the reference stepper on plant_rigid's Python source (numba not needed); it
    gives the kernel's bits, stuck joints breaking away included."""
    monkeypatch.setenv("CRANE_PLANT_KERNEL", "0")
    slow = ArmPlant("crane-x7", seed=4)
    monkeypatch.delenv("CRANE_PLANT_KERNEL")
    fast = ArmPlant("crane-x7", seed=4)
    assert slow._stepper._mass_and_bias is plant_rigid.mass_and_bias and fast.kernel
    rng = np.random.default_rng(2)
    for k in range(30):
        cmd, ext = _drive(k, 3, rng)
        for p in (fast, slow):
            p.set_external_torque(ext)
            p.step(cmd, PERIOD)
        assert fast.q.tobytes() == slow.q.tobytes() and fast.dq.tobytes() == slow.dq.tobytes(), k
    assert np.all(fast.dq != 0.0)  # every joint broke away from rest


def _trajectory_hash(plant: ArmPlant, steps: int = 200) -> str:
    from tests.test_plant_joints import _trajectory_hash as hashed

    return hashed(plant, steps)


# sha256[:16] of tests/test_plant_joints.py's trajectory (state, motor torque and reading of every step) on
# the kernel, x86_64 Linux (libm's sin, cos and exp; the kernel's own arithmetic is plain IEEE)
_KERNEL_REFERENCE = {"crane-x7": "23195b13a6e4133e", "baseline": "df694052eb0cb756",
                     "hidden-cogging": "cbb1ef498f63615f"}


@pytest.mark.parametrize("name", list(_KERNEL_REFERENCE))
def test_the_kernels_trajectory_is_pinned(name):
    if (platform.system(), platform.machine()) != ("Linux", "x86_64"):
        pytest.skip("pinned on x86_64 Linux (libm may differ in the last bits elsewhere)")
    assert _trajectory_hash(ArmPlant(name, seed=3)) == _KERNEL_REFERENCE[name]


def test_the_reference_path_records_the_pinned_session(tmp_path, monkeypatch):
    from collect.runner import RunOptions, run_session
    from tests import test_collect_session_pinned as pinned

    if (platform.system(), platform.machine()) != pinned.PINNED_PLATFORM:
        pytest.skip("the digest was pinned on x86_64 Linux")
    choose = plant_backend.choose
    monkeypatch.setattr(plant_backend, "choose", lambda plant, kernel: choose(plant, False))
    out = tmp_path / "s.h5"
    run_session(RunOptions(output=out, sim=True, seed=pinned.SEED, duration=pinned.DURATION_S, status=False))
    assert pinned.session_digest(out)[0] == pinned.PINNED_DIGEST


def test_importing_the_plant_does_not_import_numba():
    """numba is imported when a plant first needs the kernel: commands that build none (--help) stay fast."""
    import subprocess
    import sys

    code = "import sys, crane_io.sim.arm_plant; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_a_kernel_that_cannot_run_here_leaves_the_reference_path(monkeypatch):
    def broken(*_args):
        raise RuntimeError("no code for this machine")

    monkeypatch.setattr(plant_kernel, "compiled", lambda: (broken, broken, broken))
    with pytest.warns(UserWarning, match="reference path"):
        plant = ArmPlant("crane-x7")
    assert not plant.kernel
    with pytest.raises(RuntimeError, match="no code"):
        ArmPlant("crane-x7", kernel=True)


def test_only_the_compiled_stepper_takes_array_commands_and_the_lockstep_cycle():
    """The reference stepper hands the simulated chain's fast path back (the chain then calls step_lists);
    the compiled one takes it, except for an integrated joint's servo in a position mode."""
    cmds = np.zeros((5, 8))
    ref = ArmPlant("crane-x7", kernel=False)
    assert ref.step_command(cmds, 0, PERIOD) is False and ref.time == 0.0
    assert ref.kernel_step_args(PERIOD) is None and ref.kernel_cycle_args(PERIOD) is None
    assert ref.kernel_read_args() is None
    fast = ArmPlant("crane-x7", kernel=True)
    assert fast.step_command(cmds, 0, PERIOD) is True and fast.time == PERIOD
    assert fast.step_command(cmds, 1 << 0, PERIOD) is False and fast.time == PERIOD  # joint1's servo
    assert fast.step_command(cmds, 1 << 2, PERIOD) is True  # joint3: a held joint
    assert fast.kernel_step_args(PERIOD) is not None and fast.kernel_read_args() is not None
