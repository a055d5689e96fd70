"""`crane-train fidelity`: the force-channel metrics of a bilateral
session against hand computations on a synthetic session and truth trace with known tau_res and tau_ext,
the observer's sign convention (tau_res = -tau_ext is no error), the settle time and the contact guard,
the JSON keys, and the one-sentence refusals."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from train.cli import main
from train.evaluation.fidelity import measure_fidelity

NAMES = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "joint7", "gripper")
BILATERAL = (0, 1, 3)  # joint1, joint2, joint4; the rest are held (tau_res NaN)
RATE = 100.0
N = 500  # 5 s
SETTLE = slice(0, 100)  # t < 1.0 s: dropped with the default --settle 1
CONTACT = slice(300, 350)  # t 3.00-3.49 s: the follower touches an object
GUARD = 0.305  # s; rows 270-379 are within it of contact (0.305 keeps clear of rounding at 0.3)
NEAR = slice(270, 380)
FREE_ROWS = 400 - 110  # kept rows (100-499) outside NEAR

T = np.arange(N) / RATE
ALT = np.where(np.arange(N) % 2 == 0, 1.0, -1.0)  # +-1: RMS 1, mean 0


def signals():
    """Known signals. Follower free-motion tau_res: +-0.2 (joint1), +-0.3 (joint2), +-0.4 (joint4).
    Contact: tau_ext 2.0 on each bilateral joint; follower tau_res = -2.0 + 0.1 on joint1 (error 0.1),
    exactly -2.0 on joint2 (no error: the sign convention), +2.0 on joint4 (the wrong sign: error 4.0).
    Leader: hand torque tau_ext 1.0 everywhere, leader tau_res -1.0 + 0.05 (hand error 0.05).
    The settle rows and the guard rows hold huge values that would show if they were counted."""
    free_amp = {0: 0.2, 1: 0.3, 3: 0.4}
    res_f = np.full((N, 8), np.nan)
    res_l = np.full((N, 8), np.nan)
    ext = np.zeros((N, 8))
    ext_l = np.zeros((N, 8))
    for c in BILATERAL:
        res_f[:, c] = free_amp[c] * ALT
        res_f[NEAR, c] = 50.0
        ext[CONTACT, c] = 2.0
        res_l[:, c] = -1.0 + 0.05
        ext_l[:, c] = 1.0
    res_f[CONTACT, 0] = -2.0 + 0.1
    res_f[CONTACT, 1] = -2.0
    res_f[CONTACT, 3] = 2.0
    for c in BILATERAL:
        res_f[SETTLE, c] = 100.0
    q_f = np.tile(np.linspace(-0.5, 0.5, 8), (N, 1)) + 0.1 * np.sin(T)[:, None]
    q_l = q_f + 0.01
    q_l[SETTLE] += 1.0
    in_contact = np.zeros(N, bool)
    in_contact[CONTACT] = True
    dq = np.zeros((N, 8))
    dq[:, list(BILATERAL)] = np.where((np.arange(N) // 2) % 2 == 0, 1.0, 0.0)[:, None]  # moving half the rows
    return {"res_f": res_f, "res_l": res_l, "ext": ext, "ext_l": ext_l, "q_f": q_f, "q_l": q_l,
            "in_contact": in_contact, "dq": dq}


def write_session(path, sig, attrs=None, names=NAMES):
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": "crane-session", "format_version": 1, "rate_hz": RATE, "source": "sim",
                        "complete": True})
        f.attrs["joint_names"] = np.array(list(names), dtype=h5py.string_dtype())
        for k, v in (attrs or {}).items():
            f.attrs[k] = v
        for arm, q, res in (("follower", sig["q_f"], sig["res_f"]), ("leader", sig["q_l"], sig["res_l"])):
            g = f.create_group(arm)
            g.create_dataset("t", data=T)
            g.create_dataset("q", data=q)
            g.create_dataset("tau", data=np.zeros((N, 8)))
            g.create_dataset("tau_res", data=res.astype(np.float32))
            g.create_dataset("dq", data=sig["dq"].astype(np.float32))
    return path


def write_trace(path, sig, t=T, names=NAMES, leader=True, fmt="crane-truth-trace"):
    n = len(t)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = fmt
        f.attrs["format_version"] = 1
        f.attrs["joint_names"] = np.array(list(names), dtype=h5py.string_dtype())
        f.attrs["sign"] = "world on the arm: positive pushes the joint positive"
        f.create_dataset("t", data=t)
        f.create_dataset("tau_ext", data=sig["ext"][:n])
        if leader:
            f.create_dataset("leader/tau_ext", data=sig["ext_l"][:n])
        f.create_dataset("in_contact", data=sig["in_contact"][:n])
    return path


@pytest.fixture
def files(tmp_path):
    sig = signals()
    return (write_session(tmp_path / "s.h5", sig), write_trace(tmp_path / "s.truth.h5", sig), sig,
            tmp_path)


def run(*args):
    result = CliRunner().invoke(main, ["fidelity", *[str(a) for a in args]])
    assert "Traceback" not in result.output, result.output
    return result


def test_metrics_equal_the_hand_computation(files):
    session, trace, _, _ = files
    r = measure_fidelity(session, trace, contact_guard_s=GUARD)
    assert list(r.joints) == ["joint1", "joint2", "joint4"]
    assert r.samples == 400 and r.free_samples == FREE_ROWS and r.contact_samples == 50
    assert r.contact_s == pytest.approx(0.5)
    j1, j2, j4 = r.joints["joint1"], r.joints["joint2"], r.joints["joint4"]
    # free motion: the +-amplitude (float32-stored), neither the settle rows nor the guard rows
    assert j1["follower_false_rms"] == pytest.approx(0.2, rel=1e-6)
    assert j2["follower_false_rms"] == pytest.approx(0.3, rel=1e-6)
    assert j4["follower_false_rms"] == pytest.approx(0.4, rel=1e-6)
    assert j1["leader_rms"] == pytest.approx(0.95, rel=1e-6)
    assert j1["leader_hand_error_rms"] == pytest.approx(0.05, rel=1e-5)
    assert j1["hand_true_rms"] == pytest.approx(1.0)
    # moving and still (the dead-zone rule on the follower's dq): half the free rows each, each +-amplitude
    assert j2["moving_fraction"] == pytest.approx(0.5, abs=0.02)
    assert j2["follower_false_rms_moving"] == pytest.approx(0.3, rel=1e-6)
    assert j2["follower_false_rms_still"] == pytest.approx(0.3, rel=1e-6)
    # contact: the observer estimates -tau_ext
    assert j1["contact_error_rms"] == pytest.approx(0.1, rel=1e-5)
    assert j1["contact_true_rms"] == pytest.approx(2.0)
    assert j1["contact_error_ratio"] == pytest.approx(0.05, rel=1e-5)
    # tracking: the 0.01 rad offset after the settle time (1 rad before it)
    assert j1["tracking_rms"] == pytest.approx(0.01, rel=1e-6)
    assert j1["tracking_rms_deg"] == pytest.approx(np.degrees(0.01), rel=1e-6)


def test_force_sum_is_over_every_kept_sample(files):
    session, trace, sig, _ = files
    r = measure_fidelity(session, trace, contact_guard_s=GUARD)
    for c, name in zip(BILATERAL, ("joint1", "joint2", "joint4")):
        total = sig["res_l"][100:, c].astype(np.float32) + sig["res_f"][100:, c].astype(np.float32)
        want = np.sqrt(np.mean(total.astype(float) ** 2))
        assert r.joints[name]["force_sum_rms"] == pytest.approx(want, rel=1e-6)


def test_the_sign_convention_tau_res_equal_minus_tau_ext_is_no_error(files):
    session, trace, _, _ = files
    r = measure_fidelity(session, trace, contact_guard_s=GUARD)
    assert r.joints["joint2"]["contact_error_rms"] == 0.0  # tau_res = -tau_ext exactly
    assert r.joints["joint2"]["contact_error_ratio"] == 0.0
    assert r.joints["joint4"]["contact_error_rms"] == pytest.approx(4.0)  # tau_res = +tau_ext: twice off
    assert r.joints["joint4"]["contact_error_ratio"] == pytest.approx(2.0)


def test_the_guard_and_the_settle_time_choose_the_samples(files):
    session, trace, _, _ = files
    r = measure_fidelity(session, trace, contact_guard_s=0.0)  # only the contact rows leave free motion
    assert r.free_samples == 400 - 50
    rows = np.r_[100:270, 270:300, 350:380, 380:500]
    want = np.sqrt(np.mean(np.where((rows >= 270) & (rows < 380), 50.0, 0.2) ** 2))
    assert r.joints["joint1"]["follower_false_rms"] == pytest.approx(want, rel=1e-6)
    r = measure_fidelity(session, trace, settle_s=0.0, contact_guard_s=GUARD)
    assert r.samples == 500 and r.free_samples == FREE_ROWS + 100
    assert r.joints["joint1"]["tracking_rms"] > 0.4  # the settle rows' 1 rad offset counts now
    r = measure_fidelity(session, trace)  # the defaults: settle 1 s, guard 0.3 s
    assert r.settle_s == 1.0 and r.contact_guard_s == 0.3
    assert FREE_ROWS <= r.free_samples <= FREE_ROWS + 2


def test_without_a_truth_trace_every_sample_is_free_and_the_output_says_so(files):
    session, _, _, _ = files
    r = measure_fidelity(session)
    assert r.free_samples == 400 and r.contact_samples == 0 and r.truth_trace is None
    assert "contact_error_rms" not in r.joints["joint1"]
    assert "leader_hand_error_rms" not in r.joints["joint1"]
    assert any("no truth trace" in n for n in r.notes)
    result = run(session)
    assert result.exit_code == 0, result.output
    assert "no truth trace" in result.output and "every sample counts as free motion" in result.output


def test_text_output_is_a_table_with_units_and_a_summary(files):
    session, trace, _, _ = files
    result = run(session, "--truth-trace", trace, "--contact-guard", GUARD)
    assert result.exit_code == 0, result.output
    out = result.output
    assert "false N m" in out and "contact err N m" in out and "track rad" in out and "track deg" in out
    for name in ("joint1", "joint2", "joint4"):
        assert any(line.startswith(name) for line in out.splitlines())
    assert "joint3" not in out.split("RMS per joint")[1]  # a held joint has no row
    assert "models in the loop: leader nominal model; follower nominal model" in out
    assert "The operator feels up to 0.4 N m RMS of false force in free motion (joint4" in out
    assert "off by 200% of the true torque RMS at worst (joint4)" in out


def test_json_keys(files):
    session, trace, _, _ = files
    result = run(session, "--truth-trace", trace, "--json", "--settle", 1, "--contact-guard", GUARD)
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    for key in ("joints", "free_samples", "contact_samples", "models", "session", "truth_trace"):
        assert key in doc
    assert doc["session"] == str(session) and doc["truth_trace"] == str(trace)
    assert doc["free_samples"] == FREE_ROWS and doc["contact_samples"] == 50
    assert doc["models"] == {"leader": "nominal model", "follower": "nominal model"}
    assert set(doc["joints"]["joint1"]) == {
        "follower_false_rms", "follower_false_rms_moving", "follower_false_rms_still", "moving_fraction",
        "leader_rms", "leader_hand_error_rms", "hand_true_rms", "contact_error_rms", "contact_true_rms",
        "contact_error_ratio", "force_sum_rms", "tracking_rms", "tracking_rms_deg"}


def test_the_models_in_the_loop_are_reported(tmp_path):
    sig = signals()
    model = {"path": "/models/leader-rb", "method": "rigid-body", "effects": ["coulomb:joint=joint2"],
             "sha256": "ab" * 32}
    session = write_session(tmp_path / "s.h5", sig, attrs={"leader_model": json.dumps(model)})
    r = measure_fidelity(session)
    assert r.models == {"leader": model, "follower": "nominal model"}
    result = run(session)
    want = "leader rigid-body + coulomb:joint=joint2 (/models/leader-rb); follower nominal model"
    assert want in result.output


def test_a_trace_shorter_than_the_session_uses_the_common_part_and_says_so(files):
    session, _, sig, tmp = files
    trace = write_trace(tmp / "short.h5", sig, t=T[:450])
    r = measure_fidelity(session, trace, contact_guard_s=GUARD)
    assert r.samples == 350 and any("the first 450" in n for n in r.notes)


def one_sentence_refusal(args, *untouched):
    before = [p.read_bytes() for p in untouched]
    result = run(*args)
    assert result.exit_code != 0
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    assert [p.read_bytes() for p in untouched] == before
    return lines[0]


def test_refusals_are_one_sentence_and_leave_the_input_untouched(files):
    session, trace, sig, tmp = files
    assert "does not exist" in one_sentence_refusal([tmp / "missing.h5"])
    plain = tmp / "plain.h5"
    with h5py.File(plain, "w") as f:
        f.attrs["format"] = "something-else"
    assert "not a crane-session" in one_sentence_refusal([plain], plain)
    assert "does not exist" in one_sentence_refusal([session, "--truth-trace", tmp / "nope.h5"], session)
    assert "not a truth trace" in one_sentence_refusal([session, "--truth-trace", session], session)
    other_t = write_trace(tmp / "other_t.h5", sig, t=T + 0.5)
    msg = one_sentence_refusal([session, "--truth-trace", other_t], session, other_t)
    assert "not the truth trace of" in msg and "row 0" in msg
    other_names = write_trace(tmp / "other_names.h5", sig, names=tuple("abcdefgh"))
    assert "another session" in one_sentence_refusal([session, "--truth-trace", other_names], session,
                                                     other_names)
    no_bilateral = signals()
    no_bilateral["res_f"][:] = np.nan
    held = write_session(tmp / "held.h5", no_bilateral)
    assert "no bilateral joint" in one_sentence_refusal([held], held)
    assert "settle" in one_sentence_refusal([session, "--settle", 10], session)


def test_a_session_without_tau_res_is_refused(tmp_path):
    sig = signals()
    session = write_session(tmp_path / "s.h5", sig)
    with h5py.File(session, "a") as f:
        del f["leader/tau_res"]
    msg = one_sentence_refusal([session], session)
    assert "/leader/tau_res" in msg
