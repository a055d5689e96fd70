"""The CRANE-X7's physics, shared by the simulator (crane_io.sim) and by crane-train.

The project's own rigid-body model built with pinocchio (`arm_model`), rigid-body dynamics and the
base-parameter regressor (`dynamics`), the library of physical effects, each one object serving plant,
regressor and diagnosis (`effects`), and a saved learned model as the 500 Hz loop evaluates it
(`loop_model`). Nothing here talks to a bus or a simulated servo.
"""
