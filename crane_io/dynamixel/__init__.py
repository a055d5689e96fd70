"""The Dynamixel bus layer: one CRANE-X7 on one U2D2 through dynamixel-sdk, in SI units.

`bus.DynamixelBus` (reads, writes, retries, torque), the X-series control table (`control_table`), raw
register units (`units`, the only place raw servo units are converted), the Protocol 2.0 packets and CRC
(`packets`, `crc`), opening ports and finding adapters (`port`, `ports`, `link_registry`), named servo
faults (`faults`), the per-servo diagnostics report (`servo_report`) and the per-adapter encoder
calibration (`calibration`). Nothing here knows the physics or the simulator.
"""
