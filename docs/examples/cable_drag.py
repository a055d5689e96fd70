"""An effect of your own, loaded without editing the package:

    crane-train effects --effect-file docs/examples/cable_drag.py
    crane-train fit SESSION --model rigid-body --effect cable-drag:joint=joint1 \
        --effect-file docs/examples/cable_drag.py -o models/with-cable

The tests load this very file, so the example stays working.
"""

from crane_io.physics.effects import Effect, Param


class CableDrag(Effect):
    name = "cable-drag"
    title = "cable drag"
    description = "A cable that pulls harder the further the joint turns: c q |q|."
    signature = "the residual of {joint} grows with the square of its angle"
    params = (Param("drag", "N m/rad^2", 0.1, "drag per rad squared"),)

    def formula(self, q, dq, ddq, c, shape, ops):  # q, dq, ddq of its joint: floats or arrays
        return c[0] * q * abs(q)
