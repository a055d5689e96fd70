"""collect configuration: defaults, overrides, and one-sentence errors for bad files."""

import math

import pytest
import tomllib
from click.testing import CliRunner

from collect.cli import main
from collect.config import load_config
from crane_io.errors import ConfigError


def test_defaults_are_the_documented_skl_values_in_si():
    c = load_config()
    assert c.loop.rate_hz == 500.0
    j2 = c.controller.joints["joint2"]
    # SKL J2 = 0.11299 in RT-C-wrapper units, x 3.60 / (2.409 * 1.3) for this project's N m
    assert j2.inertia == pytest.approx(0.11299 * 3.60 / (2.409 * 1.3), rel=1e-4)
    assert (j2.kp, j2.kd, j2.kf, j2.cutoff) == (196.0, 28.0, 0.7, 15.0)
    assert c.controller.joints["joint1"].inertia == pytest.approx(0.012258 * 2.20 / (1.783 * 1.3), rel=1e-4)
    assert c.safety.velocity_limit["joint4"] == 2.5
    assert c.safety.limit_margin == pytest.approx(math.radians(5.0))
    assert c.held["joint3"] == 0.0


def test_user_file_overrides_only_what_it_names(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[loop]\nrate_hz = 250\n[controller.joint1]\nkp = 100\n")
    c = load_config(p)
    assert c.loop.rate_hz == 250.0 and c.loop.period_s == pytest.approx(0.004)
    assert c.controller.joints["joint1"].kp == 100.0
    assert c.controller.joints["joint1"].kd == 40.0  # untouched default


def test_full_configuration_round_trips_as_toml(tmp_path):
    c = load_config()
    text = c.to_toml()
    assert tomllib.loads(text) == c.values
    p = tmp_path / "again.toml"
    p.write_text(text)
    assert load_config(p).values == c.values


@pytest.mark.parametrize("text, words", [
    ("[loop]\nrate = 500\n", "unknown key 'loop.rate'"),
    ("[loop]\nrate_hz = 'fast'\n", "'loop.rate_hz'"),
    ("[loop]\nrate_hz = -5\n", "positive"),
    ("[controller]\ngravity_model = 'magic'\n", "gravity_model"),
    ("[safety]\ncurrent_fraction = 1.5\n", "current_fraction"),
    ("[controller.joint9]\nkp = 1\n", "joint9"),
    ("[loop\nrate_hz = 1\n", "not valid TOML"),
])
def test_bad_files_give_one_sentence(tmp_path, text, words):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(p)
    msg = str(info.value)
    assert words in msg and "\n" not in msg


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.toml")


def test_cli_bad_config_is_one_error_line_and_no_session(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[safety]\nwatchdog = 1\n")
    out = tmp_path / "s.h5"
    r = CliRunner().invoke(main, ["run", "--sim", "-o", str(out), "--config", str(bad), "--duration", "1"])
    assert r.exit_code != 0
    assert r.output.startswith("Error: unknown key 'safety.watchdog'")
    assert "Traceback" not in r.output
    assert not out.exists()


def test_cli_missing_port_is_one_error_line(tmp_path):
    out = tmp_path / "s.h5"
    r = CliRunner().invoke(main, ["run", "-o", str(out), "--leader-port", str(tmp_path / "ttyUSB7"),
                                  "--follower-port", str(tmp_path / "ttyUSB8"), "--duration", "1"])
    assert r.exit_code != 0
    assert r.output.startswith("Error: port ") and "does not exist" in r.output
    assert r.output.count("\n") == 1
    assert not out.exists()


def test_cli_hardware_run_needs_both_ports(tmp_path):
    r = CliRunner().invoke(main, ["run", "-o", str(tmp_path / "s.h5")])
    assert r.exit_code != 0 and "--leader-port" in r.output


def test_cli_unwritable_output_is_refused_before_the_arms_move(tmp_path):
    not_a_folder = tmp_path / "notes.txt"
    not_a_folder.write_text("keep me")
    r = CliRunner().invoke(main, ["run", "--sim", "--plant", "simple", "--duration", "1",
                                  "-o", str(not_a_folder / "s.h5")])
    assert r.exit_code != 0
    assert r.output.startswith("Error: cannot create session file") and r.output.count("\n") == 1
    assert "aligning" not in r.output  # found out before start-up, not after the alignment
    assert not_a_folder.read_text() == "keep me"
