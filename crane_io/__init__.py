"""crane_io: the CRANE-X7 arm, in three parts.

- crane_io.dynamixel: the Dynamixel bus layer (DynamixelBus on dynamixel-sdk, the control table, raw
  units, packets and CRC, ports, adapter calibration);
- crane_io.physics: the arm's physics (own pinocchio model, rigid-body dynamics and regressors, the
  effects library, contact objects, the learned model as the loop runs it), shared by sim and train;
- crane_io.sim: the simulated CRANE-X7 (emulated servo chain on the real wire protocol, the arm plant, its
  contact objects and TOML presets, transports).

Beside them: the arm description (`description`), the session file format (`session_format`), typed
errors (`errors`), stop requests (`shutdown`), the rerun view (`view`), HDF5 damage reports (`h5check`)
and the pieces both command lines share (`cli_support`).

Raw servo units exist only inside the bus layer and the simulator; everything that leaves them is SI
(rad, rad/s, rad/s^2, N m, A, s).
"""

__version__ = "0.1.0"
