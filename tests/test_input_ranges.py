"""Nonsense is refused at the edges: every option and configuration number finite and within its
documented range, every calibration file checked, each refusal one sentence with exit 2 before anything
is written. The fuzz tests damage valid files at random: the loaders answer with one CraneError sentence
or a valid result, never another exception, and never change the file."""

import os

import click
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from collect.cli import main as collect_main
from collect.config import MAX_RATE_HZ, MIN_RATE_HZ, default_config_text, load_config
from crane_io.cli_support import SEED, Number
from crane_io.dynamixel.calibration import (
    Calibration,
    CalibrationError,
    JointCalibration,
    build_calibration,
    check_arm_name,
    load_calibration,
    save_calibration,
)
from crane_io.errors import ConfigError, CraneError
from train.cli import main as train_main
from train.settings import DEFAULT_CONFIG
from train.settings import load_config as load_train_config

FUZZ = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _one_line(result, words=""):
    assert result.exit_code == 2, result.output
    assert result.output.startswith("Error: ") and result.output.count("\n") == 1, result.output
    assert words in result.output


# ---- options ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("args, words", [
    (["--seed", "-1"], "--seed must be an integer between 0 and 4294967295, got -1"),
    (["--seed", str(2**64)], "--seed must be an integer between 0 and 4294967295"),
    (["--rate", "nan"], "--rate must be between 100 and 2000 Hz, got nan"),
    (["--rate", "inf"], "--rate must be between 100 and 2000 Hz, got inf"),
    (["--duration", "nan"], "--duration must be a positive number of seconds"),
    (["--view-every", "0"], "--view-every must be an integer of at least 1"),
    (["--joints", "joint1,,joint2"], "has an empty item"),
    (["--joints", "joint1,joint2,"], "has an empty item"),
    (["--leader-calibration", "x.toml", "--no-calibration"],
     "--leader-calibration names a calibration file but --no-calibration asks for none"),
])
def test_nonsense_run_options_are_one_sentence_before_any_file(tmp_path, args, words):
    out = tmp_path / "s.h5"
    r = CliRunner().invoke(collect_main, ["run", "--sim", "--plant", "simple", "--duration", "1",
                                          "-o", str(out), *args])
    _one_line(r, words)
    assert not out.exists()


@pytest.mark.parametrize("args, words", [
    (["--period", "inf"], "--period must be between 0.0005 and 0.01 s, got inf"),
    (["--period", "0"], "--period must be between"),
    (["--hand-delay", "nan"], "--hand-delay must be between 0 and 60 s, got nan"),
    (["--seed", "-3"], "--seed must be an integer between 0"),
    (["--encoder-offset", "joint2=nan"], "is not a number of radians between -pi and pi"),
    (["--encoder-offset", "joint2=1e300"], "is not a number of radians between -pi and pi"),
])
def test_nonsense_sim_serve_options_are_one_sentence(tmp_path, args, words):
    r = CliRunner().invoke(collect_main, ["sim-serve", "--link", str(tmp_path / "arm"), *args])
    _one_line(r, words)
    assert not (tmp_path / "arm").exists()


@pytest.mark.parametrize("args, words", [
    (["diagnose", "m", "s.h5", "--min-reduction", "nan"], "--min-reduction must be between 0 and 1, got nan"),
    (["fit", "s.h5", "--model", "mlp-masked", "-o", "m", "--seed", "-1"], "--seed must be an integer"),
    (["fit", "s.h5", "--model", "mlp-masked", "-o", "m", "--alpha", "nan"], "--alpha must be a number"),
    (["fit", "s.h5", "--model", "mlp-masked", "-o", "m", "--epochs", "-5"], "--epochs must be an integer"),
    (["sweep", "s.h5", "-o", "w", "--batch-size", "0"], "--batch-size must be an integer of at least 1"),
    (["fidelity", "s.h5", "--settle", "inf"], "--settle must be a number of at least 0 s, got inf"),
    (["report", "m", "s.h5", "-o", "r.html", "--seed", str(2**64)], "--seed must be an integer"),
    (["import", "x.csv", "-o", "s.h5", "--map", "t=t", "--rate", "-inf"], "--rate must be a number greater"),
])
def test_nonsense_train_options_are_one_sentence(tmp_path, args, words):
    os.chdir(tmp_path)
    r = CliRunner().invoke(train_main, args)
    _one_line(r, words)
    assert os.listdir(tmp_path) == []


def test_the_number_type_takes_what_its_range_allows():
    rate = Number(float, MIN_RATE_HZ, MAX_RATE_HZ, unit="Hz")
    assert rate.convert("100", None, None) == 100.0 and rate.convert(" 2000 ", None, None) == 2000.0
    for bad in ("99.9", "2000.5", "nan", "-inf", "fast", "", True):
        with pytest.raises(click.BadParameter, match="must be between 100 and 2000 Hz"):
            rate.convert(bad, None, None)
    assert SEED.convert("4294967295", None, None) == 2**32 - 1
    with pytest.raises(click.BadParameter):
        SEED.convert("1.5", None, None)
    assert Number(float, 0, low_open=True).convert("1e-9", None, None) == 1e-9
    with pytest.raises(click.BadParameter, match="greater than 0"):
        Number(float, 0, low_open=True).convert("0", None, None)


# ---- configurations ------------------------------------------------------------------------------------

@pytest.mark.parametrize("rate", [100.0, 150.0, 199.0, 500.0, 2000.0])
def test_every_documented_rate_runs_with_the_defaults(rate):
    assert load_config().with_rate(rate).loop.rate_hz == rate


def test_the_dither_frequency_is_checked_only_with_the_dither_on(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[controller]\ndither_amplitude = 0.05\n")
    assert load_config(p).with_rate(200.0).loop.rate_hz == 200.0
    with pytest.raises(ConfigError, match="dither_frequency.*with the dither on"):
        load_config(p).with_rate(150.0)


@pytest.mark.parametrize("text, words", [
    ("[held]\njoint3_deg = 1e6\n", "c.toml must be an angle within joint3's limits, -157 to 157 deg"),
    ("[held]\njoint4_deg = 10.0\n", "joint4's limits"),
    ("[held]\njoint2_deg = nan\n", "'held.joint2_deg'"),
    ("[operator.start_deg]\njoint2 = -100.0\n", "'operator.start_deg.joint2'"),
    ("[loop]\nspin_s = 1.0\n", "c.toml must be at most one control period"),
    ("[loop]\nstatus_hz = 1e9\n", "'loop.status_hz'"),
    ("[safety]\nhoming_speed = 1e6\n", "at most the smallest safety.velocity_limit (2 rad/s)"),
])
def test_configuration_numbers_outside_their_ranges_are_refused(tmp_path, text, words):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(p)
    assert words in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("text, words", [
    ("[mlp]\nepochs = -5\n", "[mlp] epochs must be at least 1"),
    ("[mlp]\nhidden = 0\n", "[mlp] hidden must be at least 1"),
    ("[mlp]\nlr = 0.0\n", "[mlp] lr must be greater than 0"),
    ("[mlp]\nlr = nan\n", "[mlp] lr must be a finite number"),
    ("[mlp]\nbetas = [0.9, 1.5]\n", "[mlp] betas must be two numbers in [0, 1)"),
    ("[splits]\nn_val = 0\n", "[splits] n_val must be at least 1"),
    ("[preprocess]\nsplit_gap_s = 0.0\n", "[preprocess] split_gap_s must be greater than 0"),
])
def test_train_settings_outside_their_ranges_are_refused(tmp_path, text, words):
    p = tmp_path / "t.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_train_config(p)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_mlp_epochs_below_one_is_one_sentence_on_the_command_line(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text("[mlp]\nepochs = -5\n")
    session = tmp_path / "s.h5"
    session.write_bytes(b"")
    r = CliRunner().invoke(train_main, ["fit", str(session), "--model", "mlp-masked",
                                        "-o", str(tmp_path / "m"), "--config", str(p)])
    _one_line(r, "[mlp] epochs must be at least 1")
    assert not (tmp_path / "m").exists()


# ---- calibration files ---------------------------------------------------------------------------------

GOOD_CALIBRATION = """[arm]
name = "left arm"
key = "FT6Z5Q1I"
created = "2026-11-24T08:00:00Z"
[joints.joint1]
offset_rad = 0.0123
min_rad = -2.5
max_rad = 2.4
[joints.joint2]
offset_rad = -0.004
"""


@pytest.mark.parametrize("text, words", [
    (GOOD_CALIBRATION + "[joints.joint9]\noffset_rad = 0.0\n", "names unknown joint 'joint9'"),
    (GOOD_CALIBRATION.split("[joints.joint1]")[0].replace("[arm]", "[arms]")
     + "[joints.joint1]\noffset_rad = 0.0\n", "unknown"),
    ("[joints.joint1]\noffset_rad = 0.0\n", "has no [arm] table"),
    (GOOD_CALIBRATION.replace("min_rad = -2.5", "min_rad = 2.5"), "must have min_rad <= max_rad"),
    (GOOD_CALIBRATION.replace("max_rad = 2.4\n", ""), "needs both min_rad and max_rad"),
    (GOOD_CALIBRATION.replace("offset_rad = 0.0123", "offset_rad = nan"), "must be a finite number, got nan"),
    (GOOD_CALIBRATION.replace("max_rad = 2.4", "max_rad = inf"), "must be a finite number, got inf"),
    (GOOD_CALIBRATION.replace("offset_rad = 0.0123", 'offset_rad = "0.01"'), "must be a finite number"),
    (GOOD_CALIBRATION.replace("offset_rad = 0.0123", "offset_rad = true"), "must be a finite number"),
    (GOOD_CALIBRATION.replace("offset_rad = 0.0123", "offset_rad = 3.0"), "not within ±20 deg"),
    (GOOD_CALIBRATION.replace('name = "left arm"', "name = 5"), "[arm] name must be text"),
    (GOOD_CALIBRATION.replace('name = "left arm"', 'name = "a\\nb"'), "an arm name must be"),
    (GOOD_CALIBRATION.replace('name = "left arm"', 'name = ""'), "an arm name must be"),
    (GOOD_CALIBRATION.replace('key = "FT6Z5Q1I"', 'key = "../x"'), "[arm] key must be"),
    ("joints = 3\n[arm]\nname = 'x'\n", "[joints] must be a table"),
    (GOOD_CALIBRATION.replace("[joints.joint2]", "[joints.joint2]\nspeed = 1"), "unknown key 'speed'"),
])
def test_a_calibration_file_that_cannot_be_right_is_one_sentence(tmp_path, text, words):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_binary_a_folder_and_a_fifo_are_not_calibrations(tmp_path):
    garbage = tmp_path / "g.toml"
    garbage.write_bytes(bytes(range(256)) * 4)
    fifo = tmp_path / "f.toml"
    os.mkfifo(fifo)
    for path, words in ((garbage, "not UTF-8 text"), (tmp_path, "cannot read the calibration"),
                        (fifo, "not a regular file"), (tmp_path / "none.toml", "No such file")):
        with pytest.raises(CalibrationError, match=words):
            load_calibration(path)


def test_arm_names_are_checked_before_they_reach_a_file():
    assert check_arm_name("left arm (2)") == "left arm (2)"
    for bad in ("", "   ", "a\nb", "\x1b[31mred", "x" * 65, 5):
        with pytest.raises(CalibrationError, match="an arm name must be"):
            check_arm_name(bad)
    with pytest.raises(CalibrationError):
        build_calibration("left\narm", "KEY", ["joint1"], [0.0])


@pytest.mark.parametrize("name", ["", "left\narm", "\x1b[2Jx"])
def test_calibrate_refuses_a_bad_arm_name_before_opening_the_port(tmp_path, name):
    port = tmp_path / "no-such-port"  # opening it would fail with a sentence about the port instead
    r = CliRunner().invoke(collect_main, ["calibrate", "--port", str(port), "--arm", name,
                                          "--output", str(tmp_path / "c.toml")], input="\n\n")
    assert r.exit_code == 2, r.output
    assert "an arm name must be" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "c.toml").exists()


def test_a_good_calibration_still_loads(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(GOOD_CALIBRATION)
    cal = load_calibration(path)
    assert cal.name == "left arm" and cal.joints["joint1"] == JointCalibration(0.0123, -2.5, 2.4)
    again = load_calibration(save_calibration(Calibration("b", "K", cal.joints), tmp_path / "d.toml"))
    assert again.joints == cal.joints


# ---- fuzz: damaged files -------------------------------------------------------------------------------

def _damage(text: str):
    """A strategy: `text` as bytes with random bytes replaced, deleted, inserted or lines swapped."""
    data = text.encode()

    @st.composite
    def damaged(draw):
        out = bytearray(data)
        for _ in range(draw(st.integers(1, 4))):
            kind = draw(st.sampled_from(["replace", "delete", "insert", "value"]))
            at = draw(st.integers(0, max(len(out) - 1, 0)))
            if kind == "replace" and out:
                out[at] = draw(st.integers(0, 255))
            elif kind == "delete":
                del out[at:at + draw(st.integers(1, 40))]
            elif kind == "insert":
                out[at:at] = draw(st.binary(min_size=1, max_size=12))
            else:  # a plausible but wrong value after an equals sign
                eq = out.find(b"=", at)
                end = out.find(b"\n", eq) if eq >= 0 else -1
                if eq >= 0 and end >= 0:
                    value = draw(st.sampled_from([b"nan", b"inf", b"-inf", b"1e308", b"-1", b"0", b"true",
                                                  b'"x"', b"[]", b"[1, 2]", b"{}", b"99999999999999999999",
                                                  b'"\\u001b[31m"', b"2026-01-01"]))
                    out[eq + 1:end] = b" " + value
        return bytes(out)

    return damaged()


def _loads_or_one_sentence(load, path, data):
    try:
        load(path)
    except CraneError as exc:
        assert "\n" not in str(exc) and str(exc), repr(str(exc))
    assert path.read_bytes() == data


@FUZZ
@given(data=_damage(GOOD_CALIBRATION))
def test_damaged_calibration_files_are_one_sentence(tmp_path, data):
    path = tmp_path / "c.toml"
    path.write_bytes(data)
    _loads_or_one_sentence(load_calibration, path, data)


@FUZZ
@given(data=_damage(default_config_text()))
def test_damaged_collect_configurations_are_one_sentence(tmp_path, data):
    path = tmp_path / "bilateral.toml"
    path.write_bytes(data)
    _loads_or_one_sentence(load_config, path, data)


@FUZZ
@given(data=_damage(DEFAULT_CONFIG.read_text()))
def test_damaged_train_configurations_are_one_sentence(tmp_path, data):
    path = tmp_path / "train.toml"
    path.write_bytes(data)
    _loads_or_one_sentence(load_train_config, path, data)



def test_an_error_naming_a_file_with_escape_codes_prints_them_escaped(tmp_path):
    r = CliRunner().invoke(collect_main, ["run", "--sim", "--plant", "simple", "--duration", "1",
                                          "-o", str(tmp_path / "s.h5"), "--config", "\x1b[2J\nc.toml"])
    _one_line(r, "\\x1b[2J\\nc.toml does not exist")
    assert "\x1b" not in r.output


def test_a_run_with_a_seed_out_of_range_is_refused_before_any_file_from_python_too(tmp_path):
    from collect.runner import RunOptions, run_session

    for seed in (-1, 2**64, 1.5):
        with pytest.raises(ConfigError, match="`seed` must be an integer between 0 and 4294967295"):
            run_session(RunOptions(output=tmp_path / "s.h5", sim=True, plant="simple", duration=0.1,
                                   seed=seed, status=False))
        assert os.listdir(tmp_path) == []


def test_effect_shapes_and_sweep_sizes_are_finite_and_bounded():
    from train.cli.options import parse_sizes
    from train.settings import parse_effect

    assert parse_effect("stribeck:joint=joint2,stribeck_velocity=0.05")[2] == {"stribeck_velocity": 0.05}
    for value in ("nan", "inf", "x"):
        bad = f"stribeck:stribeck_velocity={value}"
        with pytest.raises(ConfigError, match="must be a finite number"):
            parse_effect(bad)
    assert parse_sizes("300:900:300") == [300, 600, 900]
    for bad in ("1:100000000000:1", "1:5000:1", "1,2,1000000000", "0:10:1"):
        with pytest.raises(ConfigError, match="is not START:STOP:STEP"):
            parse_sizes(bad)
