"""collect.runner.BilateralRun phase by phase: leaving the `with`, whatever happened between the phases,
runs the safe stop and the close to their end (torque off, the file complete or none, the signal
handlers back) and raises what ended the run."""

import signal

import h5py
import pytest

from collect.recorder import read_events
from collect.runner import BilateralRun, RunOptions
from tests.recording import torque_off_everywhere

CONFIG = """
[loop]
status_hz = 0
[operator.start_deg]
joint2 = 0.0
joint4 = 0.0
"""


@pytest.fixture
def opts(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text(CONFIG)
    return RunOptions(output=tmp_path / "s.h5", sim=True, plant="simple", duration=0.2, config=cfg, seed=2,
                      status=False)


def test_the_phases_record_a_complete_session(opts):
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with BilateralRun(opts) as run:
        run.start()
        run.align()
        run.record()
    assert run.result.end_reason == "duration" and run.result.cycles == 100
    assert torque_off_everywhere(run.sims)
    assert {s: signal.getsignal(s) for s in handlers} == handlers
    with h5py.File(opts.output, "r") as f:
        assert f.attrs["complete"] and f.attrs["end_reason"] == "duration"
        states = [e["message"] for e in read_events(f) if e["kind"] == "torque_state"]
        assert states == ["leader: torque off on 8 of 8 servos", "follower: torque off on 8 of 8 servos"]


def test_an_error_between_the_phases_still_stops_both_arms(opts):
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    with pytest.raises(RuntimeError, match="between the phases"):
        with BilateralRun(opts) as run:
            run.start()
            assert all(bus.torque_enabled for bus in run.buses.values())
            raise RuntimeError("between the phases")
    assert run.result.end_reason == "error" and run.closed
    assert torque_off_everywhere(run.sims)
    assert all(not bus.is_open for bus in run.buses.values())
    assert not opts.output.exists()  # stopped before recording: no session file
    assert {s: signal.getsignal(s) for s in handlers} == handlers


def test_a_stop_request_between_the_phases_is_a_normal_end(opts):
    with BilateralRun(opts) as run:
        run.start()
        run.stop.request(signal.SIGTERM)
        run.align()  # its first read of both arms is a checkpoint: the stop is taken there
        run.record()
    assert run.result.end_reason == "terminated"
    assert torque_off_everywhere(run.sims)
    assert not opts.output.exists()
