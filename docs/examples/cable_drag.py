"""An effect of your own, loaded without editing the package:

    crane-train effects --effect-file docs/examples/cable_drag.py
    crane-train fit SESSION --model rigid-body --effect cable-drag:joint=joint1 \
        --effect-file docs/examples/cable_drag.py -o models/with-cable

The tests load this very file, so the example stays working.
"""

import numpy as np

from crane_io.physics.effects import Effect, Param
from crane_io.physics.effects.base import joint_columns


class CableDrag(Effect):
    name = "cable-drag"
    title = "cable drag"
    description = "A cable that pulls harder the further the joint turns: c q |q|."
    signature = "the residual of {joint} grows with the square of its angle"
    params = (Param("drag", "N m/rad^2", 0.1, "drag per rad squared"),)

    def _columns(self, q, dq, ddq, joint, shape):
        return joint_columns(len(q), q.shape[1], joint, q[:, joint] * np.abs(q[:, joint]))
