"""What a new user types wrong (found by using crane-collect as one): every mistake is one "Error:"
sentence with the right exit status, before anything moves, and leaves no file or folder behind."""

import io
import os

import pytest
from click.testing import CliRunner

from collect.cli import main
from collect.config import load_config
from collect.runner import RunResult
from collect.status import print_summary
from crane_io.errors import ConfigError, HardwareError
from crane_io.sim.plant_config import load_plant_config


def _run(*args):
    return CliRunner().invoke(main, ["run", *args])


def _one_error(r, code=2):
    assert r.exit_code == code, r.output
    assert r.output.startswith("Error: ") and r.output.count("\n") == 1, r.output
    assert "Traceback" not in r.output and "aligning" not in r.output


# ---- crane-collect run: options and output --------------------------------------------------------

@pytest.mark.parametrize("duration, words", [
    ("inf", "--duration must be a positive number of seconds"),   # was an OverflowError after alignment
    ("1e-9", "shorter than one control period"),                   # was an empty session, exit 0
    ("-1", "--duration must be a positive number"),
])
def test_a_duration_that_cannot_record_anything_is_refused_and_the_old_file_kept(tmp_path, duration, words):
    out = tmp_path / "s.h5"
    out.write_bytes(b"an older session")
    r = _run("--sim", "--plant", "simple", "--duration", duration, "-o", str(out), "--force")
    _one_error(r)
    assert words in r.output
    assert out.read_bytes() == b"an older session"


def test_an_empty_output_name_is_refused_as_such(tmp_path):
    os.chdir(tmp_path)
    r = _run("--sim", "--plant", "simple", "--duration", "1", "-o", "")
    _one_error(r)
    assert "-o needs the name of a session file" in r.output  # was ". already exists"


def test_a_file_in_the_way_of_the_output_folder_is_named(tmp_path):
    notes = tmp_path / "notes.txt"
    notes.write_text("keep me")
    r = _run("--sim", "--plant", "simple", "--duration", "1", "-o", str(notes / "day1" / "s.h5"))
    _one_error(r)
    assert f"{notes} is a file, not a folder" in r.output
    assert notes.read_text() == "keep me"


def test_a_refused_hardware_run_leaves_no_new_folder_behind(tmp_path):
    out = tmp_path / "day1" / "sub" / "s.h5"
    r = _run("-o", str(out), "--leader-port", str(tmp_path / "ttyUSB7"),
             "--follower-port", str(tmp_path / "ttyUSB8"))
    _one_error(r, code=3)
    assert "does not exist" in r.output
    assert not (tmp_path / "day1").exists()


def test_missing_output_folders_are_still_made_for_a_run_that_records(tmp_path):
    out = tmp_path / "a" / "b" / "s.h5"
    r = _run("--sim", "--plant", "simple", "--duration", "0.02", "--quiet", "-o", str(out))
    assert r.exit_code == 0, r.output
    assert out.is_file()


@pytest.mark.parametrize("rate", ["50", "0", "nan", "5000"])
def test_a_rate_the_controller_cannot_run_at_is_refused_naming_the_option(tmp_path, rate):
    r = _run("--sim", "--plant", "simple", "--duration", "1", "--rate", rate, "-o", str(tmp_path / "s.h5"))
    _one_error(r)
    assert r.output.startswith("Error: --rate must be between 100 and 2000 Hz")  # 50 Hz: safety stop
    assert not (tmp_path / "s.h5").exists()


# ---- the --config file ----------------------------------------------------------------------------

@pytest.mark.parametrize("text, words", [
    ("[loop]\nrate_hz = 50\n", "c.toml must be between 100 and 2000 Hz"),
    ("[safety]\nwatchdog_s = '0.2'\n", "c.toml must be a number, got '0.2'"),
    ("[safety]\nerror_budget_consecutive = 2.5\n", "must be an integer"),
    # both were accepted and ended after torque-on in "goal current ... is not a finite number"
    ("[controller]\ngravity_model = 'coefficients'\ngravity_m0 = nan\n", "'controller.gravity_m0'"),
    ("[operator.start_deg]\njoint2 = nan\n", "'operator.start_deg.joint2'"),
])
def test_config_values_are_checked_before_start(tmp_path, text, words):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(p)
    assert words in str(info.value) and "\n" not in str(info.value)


# ---- ports ----------------------------------------------------------------------------------------

def test_a_port_that_is_a_regular_file_is_named_as_such_and_left_alone(tmp_path):
    f = tmp_path / "session.h5"
    f.write_bytes(b"data")
    r = CliRunner().invoke(main, ["check", "--port", str(f)])
    assert r.exit_code == 3
    assert f"Error: {f} is a regular file, not a serial port" in r.output  # was "Inappropriate ioctl"
    assert f.read_bytes() == b"data"
    r = _run("-o", str(tmp_path / "s.h5"), "--leader-port", str(f), "--follower-port", str(tmp_path))
    assert r.exit_code == 3 and "is a regular file, not a serial port" in r.output
    assert not (tmp_path / "s.h5").exists() and f.read_bytes() == b"data"


def test_a_character_device_that_is_not_a_tty_is_not_a_serial_port():
    from crane_io.dynamixel.port import open_port

    with pytest.raises(HardwareError, match="/dev/null is not a serial port"):
        open_port("/dev/null")


# ---- plant TOML files -----------------------------------------------------------------------------

@pytest.mark.parametrize("text, words", [
    ("sensor = 3\n", "sensor must be a table"),                                # was a TypeError
    ("known = 3\n", "known must be a table"),                                  # was an AttributeError
    ("[sensor]\nposition_noise_probability = 2\n", "at most 1"),              # was accepted
    ("[overload]\nenabled = 'false'\n", "enabled must be true or false"),     # was read as true
    ("[limits]\nstiffness = nan\n", "finite number"),                         # was accepted
    ("[sensor]\ncurrent_noise_lsb = inf\n", "finite number"),                 # was accepted
    ("[initial]\njoint1 = nan\n", "[initial] joint1 must be a finite number"),  # was accepted
    ("seed = 1.5\n", "seed must be an integer"),                               # was truncated to 1
])
def test_bad_plant_files_are_one_sentence(tmp_path, text, words):
    p = tmp_path / "p.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_plant_config(p)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_a_plant_file_that_is_not_text_or_not_a_file(tmp_path):
    p = tmp_path / "p.toml"
    p.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="cannot be read \\(not UTF-8 text\\)"):  # was UnicodeDecodeError
        load_plant_config(p)
    with pytest.raises(ConfigError, match="is not a file"):  # was "does not exist"
        load_plant_config(tmp_path)


# ---- sim-serve ------------------------------------------------------------------------------------

def test_sim_serve_does_not_replace_a_users_link_and_a_bad_link_is_input_error(tmp_path):
    from collect.cli.sim_serve import sim_serve

    data = tmp_path / "data.h5"
    data.write_bytes(b"x")
    link = tmp_path / "mylink"
    link.symlink_to(data)
    r = CliRunner().invoke(sim_serve, ["--link", str(link), "--plant", "simple"])
    assert r.exit_code == 2 and "not to a pseudo-terminal" in r.output  # was removed and replaced
    assert link.is_symlink() and os.readlink(link) == str(data)
    r = CliRunner().invoke(sim_serve, ["--link", str(tmp_path / "missing" / "x"), "--plant", "simple"])
    assert r.exit_code == 2 and "does not exist" in r.output  # input, not a hardware fault (was 3)


def test_a_stale_pty_link_is_still_replaced(tmp_path):
    from crane_io.description import default_arm
    from crane_io.sim.chain import SimulatedChain
    from crane_io.sim.simple_plant import SimplePlant
    from crane_io.sim.transport import PtyServer

    arm = default_arm()
    link = tmp_path / "crane"
    link.symlink_to("/dev/pts/999")
    with PtyServer(SimulatedChain.for_arm(arm, SimplePlant.from_arm(arm)), link) as server:
        assert os.readlink(link) == server.slave_path
    assert not link.exists() and not link.is_symlink()


# ---- the summary ----------------------------------------------------------------------------------

def test_lockstep_summary_gives_the_simulated_rate_not_the_wall_rate_as_achieved(tmp_path):
    summary = {"period_mean_s": 0.00085, "period_std_s": 1e-4, "period_p99_s": 0.0012, "period_max_s": 0.01,
               "overruns": 0.0, "rate_hz": 1176.0, "nominal_period_s": 0.002}
    r = RunResult(tmp_path / "s.h5", 1000, 2.0, 2.7, "duration", None, summary)
    out = io.StringIO()
    print_summary(r, 0, out, lockstep=True)
    loop_line = next(line for line in out.getvalue().splitlines() if line.startswith("  loop:"))
    assert "500 Hz of simulated time" in loop_line and "x2.4 real time" in loop_line
    assert "achieved" not in loop_line  # the file says rate_hz_achieved = 500; so must the summary
    out = io.StringIO()
    print_summary(r, 0, out, lockstep=False)
    assert "1176 Hz achieved" in out.getvalue()


def test_a_plant_without_damping_stops_in_the_alignment_with_a_hint_and_no_file(tmp_path):
    plant = tmp_path / "mine.toml"
    plant.write_text('name = "mine"\n[[effects]]\neffect = "coulomb"\njoint = "joint2"\ncoulomb = 0.3\n')
    out = tmp_path / "s.h5"
    r = _run("--sim", "--plant", str(plant), "--duration", "1", "--quiet", "-o", str(out))
    assert r.exit_code == 3
    assert r.output.startswith("Error: safety stop while aligning") and "lacks damping" in r.output
    assert 'base = "baseline"' in r.output and not out.exists()
