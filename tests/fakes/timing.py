"""Fakes for time: a plant too slow for real time, and a line whose replies arrive late.

    plant = SlowPlant(SimplePlant.from_arm(arm), cost_s=0.02)   # every step takes 20 ms of real time
    with LateReplies(chain, link, delay_s=1.0, servo_id=4):      # a pty; servo 4's replies come 1 s late
        ...

Neither needs a busy machine: they make slowness certain, so a test asserts what the code does about
it, not how fast the machine happens to be.
"""

from __future__ import annotations

import threading
import time

from crane_io.sim.transport import PtyServer

PKT_ID = 4


class SlowPlant:
    """Wraps a plant: each `step` first sleeps `cost_s` (a machine too slow or too busy for the physics).
    Records every step's dt in `dts`."""

    def __init__(self, plant, cost_s: float):
        self.plant = plant
        self.cost_s = cost_s
        self.dts: list[float] = []

    @property
    def servo_ids(self):
        return self.plant.servo_ids

    def step(self, command, dt):
        if self.cost_s > 0:
            time.sleep(self.cost_s)
        self.dts.append(dt)
        self.plant.step(command, dt)

    def read(self):
        return self.plant.read()

    def hardware_errors(self):
        return self.plant.hardware_errors()

    def set_external_torque(self, torque):
        self.plant.set_external_torque(torque)


class LateReplies(PtyServer):
    """A PtyServer whose replies reach the line `delay_s` late: all of them, or only those of
    `servo_id` (a slow adapter, an overloaded host). Counts the delayed replies in `.delayed`."""

    def __init__(self, chain, link, delay_s: float, servo_id: int | None = None):
        super().__init__(chain, link)
        self.delay_s = delay_s
        self.servo_id = servo_id
        self.delayed = 0
        self._timers: list[threading.Timer] = []
        self._line = threading.Lock()
        self._closing = False

    def _send(self, reply: bytes) -> None:
        if self.servo_id is not None and (len(reply) <= PKT_ID or reply[PKT_ID] != self.servo_id):
            self._deliver(reply)
            return
        self.delayed += 1
        timer = threading.Timer(self.delay_s, self._deliver, (reply,))
        timer.daemon = True
        self._timers.append(timer)
        timer.start()

    def _deliver(self, reply: bytes) -> None:
        with self._line:
            if not self._closing:
                self._write_all(reply)

    def stop(self) -> None:
        with self._line:  # no late reply is written once the descriptors may close
            self._closing = True
        for timer in self._timers:
            timer.cancel()
        super().stop()


class TickingClock:
    """Stands in for the `time` module of the code under test: real time advances by `tick_s` at every
    reading (monotonic or perf_counter) and by `sleep`/`advance`, never by itself. Work then costs the
    same whatever the machine's load."""

    def __init__(self, tick_s: float = 2e-5):
        self.now = 1000.0
        self.tick_s = tick_s

    def monotonic(self) -> float:
        self.now += self.tick_s
        return self.now

    perf_counter = monotonic

    def advance(self, seconds: float) -> None:
        self.now += seconds

    sleep = advance
