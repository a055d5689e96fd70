"""A wire fault in any read of the alignment (the first, one in the middle, the last one after the move)
or in the read that starts the simulated operator is a safety stop like any other: both arms stopped
(torque off), one sentence with exit 3, no session file."""

from __future__ import annotations

import sys

import pytest

from collect import runner
from collect.alignment import SETTLE_S, SafetyStop
from collect.arm_pair import ArmPair
from collect.runner import RunOptions, run_session
from tests.fakes.faults import DropReplies
from tests.recording import TEST_CONFIG, torque_off_everywhere


def _which_read(caller) -> str:
    """Which read of both arms `caller` (a frame) is doing: first, during, last (alignment) or start."""
    if caller.f_code.co_name == "start_motion":  # the read before the session file opens
        return "start"
    if caller.f_code.co_name != "align":
        return "loop"
    local = caller.f_locals
    if "t" not in local:
        return "first"
    return "last" if local["t"] >= local["move_s"] + SETTLE_S else "during"


@pytest.mark.parametrize("where", ["first", "during", "last", "start"])
def test_a_failed_read_while_aligning_is_a_safety_stop_with_torque_off(tmp_path, monkeypatch, where):
    cfg = tmp_path / "test.toml"
    cfg.write_text(TEST_CONFIG)
    seen = {"faults": 0}
    make, read_both = runner.make_sim_arms, ArmPair.read_both

    def make_sim_arms(*args):
        seen["sims"] = make(*args)
        return seen["sims"]

    def failing_read_both(self):
        if seen["faults"] == 0 and _which_read(sys._getframe(1)) == where:
            seen["faults"] += 1
            with DropReplies(seen["sims"]["follower"].chain, count=None):  # this read only
                return read_both(self)
        return read_both(self)

    monkeypatch.setattr(runner, "make_sim_arms", make_sim_arms)
    monkeypatch.setattr(ArmPair, "read_both", failing_read_both)
    out = tmp_path / "s.h5"
    with pytest.raises(SafetyStop) as err:
        run_session(RunOptions(output=out, sim=True, plant="simple", duration=1.0, config=cfg, seed=5,
                               status=False))
    msg = str(err.value)
    assert seen["faults"] == 1 and err.value.exit_code == 3 and "\n" not in msg
    what = "before recording" if where == "start" else "while aligning"
    assert msg.startswith(f"safety stop reading the arms {what}: the follower arm failed (")
    assert torque_off_everywhere(seen["sims"])
    assert not out.exists()
