"""`crane-collect check` tells a servo that never answers from one whose replies come too late.

The late servo is a pty whose replies for one ID reach the line a fixed time late (tests/fakes/timing.py);
the silent one drops its replies. Delays are far longer than the reply timeout, and asserted as lower
bounds, so the test holds on a busy machine."""

from __future__ import annotations

import pytest
from fakes import DropReplies, LateReplies

from collect.cli.check import _row
from crane_io.dynamixel.bus import DynamixelBus
from crane_io.sim import simulated_arm

DELAY_S = 1.5  # far beyond three tries of the 0.2 s timeout below: every try of the report read fails
LATENCY_MS = 100.0  # reply timeout of each try: 2 x 100 ms + 2 ms + transmission


@pytest.fixture
def sim():
    arm = simulated_arm(return_delay_time=0)
    yield arm
    arm.close()


def test_a_late_servo_is_reported_with_how_late_its_reply_came(sim, tmp_path):
    link = tmp_path / "crane"
    with LateReplies(sim.chain, link, delay_s=DELAY_S, servo_id=4) as server:
        with DynamixelBus(str(link), latency_ms=LATENCY_MS) as bus:
            rows = {r["id"]: r for r in bus.servo_report(late_listen_s=DELAY_S * 4)}
    assert server.delayed >= 1
    late = rows[4]
    assert late["answering"] is False and late["tries"] == 3
    assert late["timeout_s"] == pytest.approx(0.2, abs=0.01)
    assert late["late_reply_s"] >= DELAY_S  # the probe's own reply, not an earlier read's
    assert all(rows[sid]["answering"] for sid in rows if sid != 4)
    text = _row(late)
    assert "REPLIES TOO LATE" in text and "NOT ANSWERING" not in text
    assert f"after {late['late_reply_s'] * 1e3:.0f} ms" in text and "timeout" in text
    assert "latency timer" in text and "crane-collect ports" in text


def test_a_silent_servo_is_reported_as_not_answering_at_all(sim):
    with DropReplies(sim.chain, count=None, servo_id=6):
        with DynamixelBus(sim.url) as bus:
            rows = {r["id"]: r for r in bus.servo_report(late_listen_s=0.2)}
            attempts = bus.stats.attempts
            quick = bus.servo_report()[4]  # the stop's torque report: no second look, no waiting
            assert quick["answering"] is False and quick["late_reply_s"] is None and quick["listen_s"] == 0
            assert bus.stats.attempts - attempts == 8 + 2  # one read per servo, two retries for ID 6
    silent = rows[6]
    assert silent["answering"] is False and silent["late_reply_s"] is None and silent["listen_s"] == 0.2
    text = _row(silent)
    assert "NOT ANSWERING" in text and "no reply at all" in text and "power" in text
    assert all(rows[sid]["answering"] for sid in rows if sid != 6)


def test_a_servo_that_answers_the_second_look_in_time_is_intermittent():
    row = {"id": 5, "joint": "joint4", "expected_model": "XM430-W350", "answering": False, "tries": 3,
           "timeout_s": 0.004, "listen_s": 0.5, "late_reply_s": 0.0012}
    assert "ANSWERS ONLY SOMETIMES" in _row(row) and "1.2 ms" in _row(row)


def test_check_prints_which_servo_is_late_and_exits_1(sim, tmp_path, monkeypatch):
    """The whole command over a pty: the late servo's line, the others' rows, exit status 1."""
    from click.testing import CliRunner

    import crane_io.dynamixel.servo_report
    from collect.cli import main

    monkeypatch.setattr(crane_io.dynamixel.servo_report, "LATE_REPLY_LISTEN_S", DELAY_S * 4)
    link = tmp_path / "crane"
    with LateReplies(sim.chain, link, delay_s=DELAY_S, servo_id=7):
        result = CliRunner().invoke(main, ["check", "--port", str(link)])
    assert result.exit_code == 1, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip().startswith("ID")]
    assert len(lines) == 8
    assert "REPLIES TOO LATE" in lines[5] and lines[5].strip().startswith("ID  7")
    others = lines[:5] + lines[6:]
    assert all("REPLIES TOO LATE" not in ln and "NOT ANSWERING" not in ln for ln in others)


def test_the_report_reads_through_the_buss_public_api_only():
    """servo_report.py touches no private member of the bus it is given, and every member it touches is
    the bus's (read from the source, so a new private access fails here)."""
    import ast
    from pathlib import Path

    from crane_io.dynamixel import servo_report

    tree = ast.parse(Path(servo_report.__file__).read_text())
    used = {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name) and node.value.id == "bus"}
    assert {"read_block", "late_reply_s", "reply_timeout_s", "require_open"} <= used
    assert [name for name in used if name.startswith("_")] == []
    bus = DynamixelBus("dxlsim://nothing-opened")
    assert all(hasattr(bus, name) for name in used)
