"""`crane-train import`: another logger's CSV or NPZ columns become a session that crane-train reads; a CSV
written from a session gives back the same arrays; what cannot be mapped is one sentence, the input is
never touched and an existing output is kept without --force."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from crane_io.description import default_arm
from crane_io.dynamixel.units import AMPERE_PER_CURRENT_LSB, POSITION_CENTER, RAD_PER_PULSE
from tests.sessions import write_synthetic_session
from train.cli import main
from train.data.importer import ImportMapError, ImportUnits, import_session, parse_map
from train.data.session import read_session

ARM = default_arm()
NAMES = ARM.joint_names


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path, _ = write_synthetic_session(tmp_path_factory.mktemp("imp") / "s.h5", 4.0, rate_hz=500, seed=2)
    return read_session(path)


def _write_csv(path, header, columns, delimiter=","):
    data = np.column_stack(columns)
    np.savetxt(path, data, delimiter=delimiter, header=delimiter.join(header), comments="", fmt="%.17g")
    return path


def _invoke(*args):
    return CliRunner().invoke(main, ["import", *map(str, args)])


def _maps(q="q_{}", tau="tau_{}", sig="tau"):
    out = ["--map", "t=time"]
    for n in NAMES:
        out += ["--map", f"{n}.q={q.format(n)},{n}.{sig}={tau.format(n)}"]
    return out


def test_a_csv_written_from_a_session_gives_back_the_same_arrays(session, tmp_path):
    csv = _write_csv(tmp_path / "log.csv", ["time"] + [f"q_{n}" for n in NAMES] + [f"tau_{n}" for n in NAMES],
                     [session.t, session.q, session.tau])
    before = csv.read_bytes()
    out = tmp_path / "imported.h5"
    r = _invoke(csv, "-o", out, *_maps(), "--source", "other-lab")
    assert r.exit_code == 0, r.output
    assert "2000 samples" in r.output and "500 Hz" in r.output
    back = read_session(out)
    assert back.joint_names == NAMES and back.rate_hz == 500 and back.source == "other-lab"
    assert np.array_equal(back.t, session.t)
    assert np.array_equal(back.q, session.q)
    assert np.array_equal(back.tau, session.tau)
    assert back.attrs["complete"] is True and back.attrs["imported_from"] == "log.csv"
    assert csv.read_bytes() == before
    # crane-train reads it like any session
    info = CliRunner().invoke(main, ["info", str(out)])
    assert info.exit_code == 0 and "other-lab" in info.output, info.output


def test_units_currents_and_a_subset_of_joints(session, tmp_path):
    """Degrees, milliseconds from an arbitrary start, milliamperes with a given and a default torque
    constant, semicolons; only joints 1, 2, 4, given out of order."""
    kt = {"joint1": 1.783, "joint2": ARM.joint("joint2").torque_constant,
          "joint4": ARM.joint("joint4").torque_constant}
    cols = ["joint4", "joint1", "joint2"]
    idx = [NAMES.index(n) for n in cols]
    current_ma = [session.tau[:, i] / kt[n] * 1e3 for n, i in zip(cols, idx)]
    header = ["stamp_ms"] + [f"{n}_deg" for n in cols] + [f"{n}_mA" for n in cols]
    csv = _write_csv(tmp_path / "lab.csv", header,
                     [1.7e6 + session.t * 1e3, np.degrees(session.q[:, idx]), *current_ma], delimiter=";")
    out = tmp_path / "s.h5"
    maps = ["--map", "t=stamp_ms"] + [x for n in cols for x in ("--map", f"{n}.q={n}_deg,{n}.current={n}_mA")]
    r = _invoke(csv, "-o", out, *maps, "--angle-unit", "deg", "--time-unit", "ms", "--current-unit", "mA",
                "--torque-constant", "joint1=1.783")
    assert r.exit_code == 0, r.output
    back = read_session(out)
    assert back.joint_names == ("joint1", "joint2", "joint4")  # the arm's order
    order = [NAMES.index(n) for n in back.joint_names]
    assert np.allclose(back.t, session.t, atol=1e-9)  # shifted to start at 0
    assert np.allclose(back.q, session.q[:, order], atol=1e-12)
    assert np.allclose(back.tau, session.tau[:, order], atol=1e-12)
    assert back.attrs["tau_source"] == ["imported_current"] * 3
    assert np.allclose(back.attrs["torque_constants"], [kt[n] for n in back.joint_names])
    assert back.attrs["import_time_offset_s"] == pytest.approx(1700.0)


def test_npz_with_raw_pulses_and_array_columns(session, tmp_path):
    pulses = np.rint(session.q / RAD_PER_PULSE + POSITION_CENTER)
    kt = np.array([j.torque_constant for j in ARM.joints])
    raw_current = np.rint(session.tau / kt / AMPERE_PER_CURRENT_LSB)
    npz = tmp_path / "log.npz"
    np.savez(npz, t_us=np.rint(session.t * 1e6), pos=pulses, cur=raw_current)
    spec = parse_map(["t=t_us"] + [f"{n}.q=pos[{i}],{n}.current=cur[{i}]" for i, n in enumerate(NAMES)])
    s = import_session(npz, tmp_path / "s.h5", spec, ImportUnits(angle="pulse", time="us", current="raw"))
    assert s.joint_names == NAMES
    back = read_session(tmp_path / "s.h5")
    assert np.allclose(back.q, (pulses - 2048) * 2 * np.pi / 4096)
    assert np.allclose(back.tau, raw_current * 2.69e-3 * kt)
    assert np.allclose(back.t, session.t)


def _refused(r, *words):
    assert r.exit_code == 2, r.output
    line = r.output.strip()
    assert line.startswith("Error: ") and "\n" not in line and "Traceback" not in line, r.output
    for w in words:
        assert w in line, line


def test_refusals_in_one_sentence_leave_input_and_output_alone(session, tmp_path):
    names = ["time", "q1", "tau1", "q2", "tau2"]
    n = 300
    t = np.arange(n) / 100.0
    good = [t, np.sin(t), np.cos(t), 0.5 * np.sin(t), t * 0.1]
    csv = _write_csv(tmp_path / "in.csv", names, good)
    maps = ["--map", "t=time,joint1.q=q1,joint1.tau=tau1,joint2.q=q2,joint2.tau=tau2"]
    out = tmp_path / "out.h5"

    _refused(_invoke(csv, "-o", out, "--map", "t=time,joint1.q=q1,joint1.tau=missing"), "no column 'missing'",
             "q1")
    _refused(_invoke(csv, "-o", out, "--map", "t=time,joint9.q=q1,joint9.tau=tau1"), "unknown joint 'joint9'")
    _refused(_invoke(csv, "-o", out, "--map", "t=time,joint1.speed=q1"), "unknown signal 'speed'")
    _refused(_invoke(csv, "-o", out, "--map", "t=time,joint1.q=q1"), "no torque for joint1")
    _refused(_invoke(csv, "-o", out, "--map", "joint1.q=q1,joint1.tau=tau1"), "no time column")
    _refused(_invoke(csv, "-o", out, "--map", "joint1.q=q1,joint1.tau=tau1"),
             "Error: --map names no time column")
    _refused(_invoke(csv, "-o", out, "--map", "t=time,joint1.q=q1,joint1.tau=tau1,joint1.current=q2"),
             "both a torque and a current")
    _refused(_invoke(csv, "-o", out, "--map", "t=time", "--map", "t=q1"), "names t twice")
    _refused(_invoke(csv, "-o", out, "--map", "nonsense"), "KEY=COLUMN")
    _refused(_invoke(tmp_path / "none.csv", "-o", out, *maps), "does not exist")
    assert not out.exists()

    back = t.copy()
    back[57] = back[55]
    _refused(_invoke(_write_csv(tmp_path / "t.csv", names, [back, *good[1:]]), "-o", out, *maps),
             "does not increase at data row 58")
    holes = good[3].copy()
    holes[[10, 20]] = np.nan
    _refused(_invoke(_write_csv(tmp_path / "nan.csv", names, [*good[:3], holes, good[4]]), "-o", out, *maps),
             "'q2' has 2 missing, NaN or infinite values (first in data row 11)")
    text = (tmp_path / "in.csv").read_text().splitlines()
    text[5] = text[5].replace(text[5].split(",")[2], "abc", 1)
    (tmp_path / "word.csv").write_text("\n".join(text) + "\n")
    _refused(_invoke(tmp_path / "word.csv", "-o", out, *maps), "column 'tau1' holds 'abc' in data row 5",
             "not a number")
    short = [c[:50] for c in good]
    _refused(_invoke(_write_csv(tmp_path / "short.csv", names, short), "-o", out, *maps), "50 data rows",
             "at least 100")
    assert not out.exists() and not list(tmp_path.glob(".out.h5.*"))

    before = csv.read_bytes()
    assert _invoke(csv, "-o", out, *maps).exit_code == 0
    stamp = out.read_bytes()
    _refused(_invoke(csv, "-o", out, *maps), "exists", "--force")
    assert "`force`" not in _invoke(csv, "-o", out, *maps).output
    assert out.read_bytes() == stamp
    _refused(_invoke(csv, "-o", csv, *maps, "--force"), "same file as the input")
    assert csv.read_bytes() == before
    assert _invoke(csv, "-o", out, *maps, "--force", "--source", "again").exit_code == 0
    assert read_session(out).source == "again"


def test_library_errors_are_typed():
    with pytest.raises(ImportMapError, match="no angle for joint2"):
        parse_map(["t=x", "joint2.tau=y"])
    # from Python the sentence names the parameter; the command line names its flag (see below)
    with pytest.raises(ImportMapError, match="^`mapping` names no time column; add t=COLUMN$"):
        parse_map(["joint1.q=q1,joint1.tau=tau1"])
    with pytest.raises(ImportMapError, match="unknown angle unit"):
        ImportUnits(angle="grad")
