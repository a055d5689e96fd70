"""crane_io: the CRANE-X7 arm — Dynamixel bus layer, control table and units, arm description,
rigid-body dynamics, the physical-effects library and the simulated servo chain.

Raw servo units exist only inside this package's bus layer and simulator; everything that leaves
it is SI (rad, rad/s, rad/s^2, N m, A, s).
"""

__version__ = "0.1.0"
