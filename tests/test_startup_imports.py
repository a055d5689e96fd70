"""Start-up of a simulated session: the plant and the controller's rigid-body model must not pull in
scipy (~0.3 s of import a run, 5 % of a 60 s lockstep session); only the regressor's base decomposition,
which a run never needs, uses it."""

import subprocess
import sys


def _loaded(code: str) -> str:
    env_code = "import os; os.environ['CRANE_PLANT_KERNEL'] = '0'; " + code  # no numba compile needed here
    out = subprocess.run([sys.executable, "-c", env_code], capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_a_simulated_arm_and_its_dynamics_do_not_import_scipy():
    code = ("import sys; from crane_io.sim.arm_plant import ArmPlant; p = ArmPlant('crane-x7'); "
            "from crane_io.physics.dynamics import ArmDynamics; d = ArmDynamics(); "
            "import numpy as np; d.inverse_dynamics(np.zeros(3), np.zeros(3), np.zeros(3)); "
            "print('scipy' in sys.modules)")
    assert _loaded(code) == "False"


def test_the_base_decomposition_still_finds_scipy():
    code = ("import sys; from crane_io.physics.dynamics import ArmDynamics; d = ArmDynamics(); "
            "w = d.base_regressor([0.1, 0.2, 0.3], [0.0] * 3, [0.0] * 3); "
            "print(w.shape[-1] > 0, 'scipy' in sys.modules)")
    assert _loaded(code) == "True True"
