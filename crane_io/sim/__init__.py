"""The simulated CRANE-X7: a chain of emulated X-series servos that answers real Protocol 2.0
bytes, backed by a plant (the physics). Users rehearse with it; tests run the real client on it."""

from __future__ import annotations

import itertools

_counter = itertools.count(1)


class SimulatedArm:
    """A simulated arm reachable in-process at `url` (dxlsim://NAME): `chain`, `plant`, `close()`."""

    def __init__(self, name: str, chain, plant):
        from crane_io.sim import transport

        self.name = name
        self.chain = chain
        self.plant = plant
        self.url = transport.register_chain(name, chain)
        self._closed = False

    def close(self) -> None:
        if not self._closed:
            from crane_io.sim import transport

            transport.unregister_chain(self.name)
            self._closed = True

    def __enter__(self) -> SimulatedArm:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"SimulatedArm(url={self.url!r}, clock={self.chain.clock!r})"


def simulated_arm(name=None, plant=None, clock="lockstep", period_s=0.002, arm=None,
                  fast_sync_read=True, return_delay_time=None, wiring=None) -> SimulatedArm:
    """A simulated CRANE-X7 on dxlsim://NAME: servos with the arm's IDs and models at 3 Mbps.

    plant: any crane_io.sim.plant_api.Plant for the arm's servo IDs (default: SimplePlant).
    clock: "lockstep" (one period per Goal Current sync write) or "wall" (real time).
    arm: an ArmDescription (default crane_io.description.default_arm()).
    fast_sync_read: False makes the servos ignore Fast Sync Read (to exercise the fallback).
    return_delay_time: raw Return Delay Time of every servo (default: the factory 250 = 500 us).
    wiring: a crane_io.sim.wiring_faults.WiringFaults planted in the arm (default: healthy wiring).
    """
    from crane_io.description import default_arm
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.simple_plant import SimplePlant
    from crane_io.sim.wiring_faults import apply_wiring_faults

    arm = default_arm() if arm is None else arm
    plant = SimplePlant.from_arm(arm) if plant is None else plant
    plant, models = apply_wiring_faults(plant, arm, wiring)
    chain = SimulatedChain(plant, models, clock=clock, period_s=period_s,
                           fast_sync_read=fast_sync_read, return_delay_time=return_delay_time)
    if name is None:
        from crane_io.sim import transport

        while True:
            name = f"arm{next(_counter)}"
            if transport.lookup_chain(name) is None:
                break
    return SimulatedArm(name, chain, plant)


__all__ = ["SimulatedArm", "simulated_arm"]
