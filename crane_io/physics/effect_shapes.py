"""The built-in effects' torque shapes, each written once, on floats.

An effect's torque is made of these shapes and its coefficients (crane_io.physics.effects.library):
its `formula` calls them (through `ops`: crane_io.physics.effects.base.SCALAR_OPS on floats, ARRAY_OPS on
arrays, where they run as the same code with numpy's exp, sin and cos: `base.on_arrays`), and the
simulated plant evaluates them in its kinetic friction and cogging (crane_io.sim.plant_layout, which both
of the plant's steppers call, one of them compiled). A change to an effect's physics is an edit here.

This module imports math only (the plant's compiled kernel compiles it).
"""

from __future__ import annotations

import math


def stribeck(v, vs):
    """exp(-(v / vs)^2): the Stribeck term's fall with speed, 1 at rest and 1/e at the velocity vs."""
    x = v / vs
    return math.exp(-(x * x))


def spring(q, k, q0):
    """k (q - q0): a spring of stiffness k relaxed at the angle q0."""
    return k * (q - q0)


def ripple(q, a_sin, a_cos, periods):
    """a_sin sin(periods q) + a_cos cos(periods q): a torque ripple with `periods` cycles per turn of q."""
    x = periods * q
    return a_sin * math.sin(x) + a_cos * math.cos(x)
