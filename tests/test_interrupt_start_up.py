"""Ctrl+C during start-up (imports, the simulated arms' kernels being compiled, before any torque is on)
ends `crane-collect run` at once with one line saying what it interrupted and exit 130; `crane-train`
ends with one line and 130 too. The latencies are printed (pytest -s), never asserted beyond a generous
bound: the machine may be busy."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from collect.kernels import compile_sentence

BIN = Path(sys.executable).parent


def _interrupt(args, delay, env=None, bound_s=20.0):
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    time.sleep(delay)
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=bound_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"still running {bound_s} s after Ctrl+C (sent {delay} s after the start)")
    latency = time.monotonic() - t0
    print(f"{Path(args[0]).name}: Ctrl+C {delay} s after the start, ended {latency:.2f} s later")
    return proc.returncode, err.decode(), out.decode()


@pytest.mark.parametrize("delay", [0.8, 1.6, 2.4])
def test_ctrl_c_while_the_kernels_compile_ends_the_run_with_one_line(tmp_path, delay):
    # a numba cache of its own, empty: the kernels are compiled from scratch, which takes many seconds,
    # so the signal surely lands before torque could be on
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    code, err, out = _interrupt([str(BIN / "crane-collect"), "run", "--sim", "--duration", "5",
                                 "-o", str(tmp_path / "s.h5")], delay, env)
    if _before_the_handler(err, "collect"):  # a busy machine had not run the command's first line yet
        assert not (tmp_path / "s.h5").exists()
        return
    assert code == 130, err
    lines = err.splitlines()
    # stderr is a pipe here: the line that says the kernels are being compiled (once the compilation has
    # taken a second), then exactly one line for the interruption
    assert lines[:-1] in ([], [compile_sentence()]), err
    assert lines[-1].startswith("crane-collect: interrupted while "), err
    assert lines[-1].endswith("; no torque was on")
    assert "Traceback" not in err and out == ""
    assert not (tmp_path / "s.h5").exists()


def _before_the_handler(err: str, package: str = "train") -> bool:
    """The traceback of a KeyboardInterrupt that came before the command's first line (`package`/cli) had
    installed its handler (the interpreter's own start, the entry script's first imports): Python's
    default, which no program can change. On a busy machine a signal sent a fraction of a second after
    the start can land there."""
    source = (Path(__file__).parents[1] / package / "cli" / "__init__.py").read_text().splitlines()
    installed = next(i for i, line in enumerate(source, 1) if line.startswith("interrupt_until_main("))
    lines = err.strip().splitlines()
    if not lines or lines[0] != "Traceback (most recent call last):" or lines[-1] != "KeyboardInterrupt":
        return False
    ours = [int(line.split('", line ')[1].split(",")[0]) for line in lines
            if line.strip().startswith("File ") and line.split('"')[1].endswith(f"{package}/cli/__init__.py")]
    return all(n <= installed for n in ours) and "crane_io/cli_support" not in err


@pytest.mark.parametrize("delay", [0.3, 0.8, 1.6])
def test_ctrl_c_in_crane_train_is_one_line_and_130(tmp_path, delay):
    """Wherever the signal lands once crane-train's first line has run (the imports, the import
    machinery's own callbacks, the command), it is one line and 130; only a command that had already
    ended on its own (the empty file refused, 2; or killed by the signal in the interpreter's own exit,
    after its one line) may finish otherwise. Never a traceback, never an interruption taken and then
    ignored. Before that first line the interpreter's own default applies (`_before_the_handler`)."""
    session = tmp_path / "s.h5"
    session.write_bytes(b"")
    code, err, _ = _interrupt([str(BIN / "crane-train"), "fit", str(session), "--model", "mlp-masked",
                               "-o", str(tmp_path / "m")], delay)
    if _before_the_handler(err):
        return
    assert "Traceback" not in err and "Exception ignored" not in err, err
    if code in (2, -signal.SIGINT):  # ended on its own; the signal may land in the interpreter's exit
        assert err.startswith("Error: ") and err.count("\n") == 1, err
    else:
        assert code == 130 and err.count("\n") == 1 and err.startswith("crane-train: interrupted"), err


LOST_IN_A_CALLBACK = """
import signal, sys, weakref
from crane_io.shutdown import resurface_lost_interrupts

class Thing:
    pass

def callback(ref):
    raise KeyboardInterrupt  # as a Ctrl+C landing inside a weakref callback of the import machinery

with resurface_lost_interrupts():
    try:
        thing = Thing()
        ref = weakref.ref(thing, callback)
        del thing  # the callback runs; its exception is unraisable
        for _ in range(400):
            __import__("time").sleep(0.01)
        print("lost")
    except KeyboardInterrupt:
        print("delivered")
"""


def test_a_ctrl_c_lost_in_a_callback_is_delivered_again():
    run = subprocess.run([sys.executable, "-c", LOST_IN_A_CALLBACK], capture_output=True, text=True,
                         timeout=120)
    assert run.stdout == "delivered\n" and run.stderr == "", (run.stdout, run.stderr)


SWALLOWING = """
import signal, sys, time
sys.argv[0] = "crane-collect"
from crane_io import shutdown
shutdown.set_activity("compiling the control kernels")
assert shutdown.arm_prompt_exit("crane-collect", "no torque was on")
signal.signal(signal.SIGINT, lambda signum, frame: None)  # taken, then lost (a broad except)
print("armed", flush=True)
while True:
    time.sleep(0.05)
"""


def test_a_swallowed_ctrl_c_still_ends_the_start_up_from_the_watcher():
    proc = subprocess.Popen([sys.executable, "-c", SWALLOWING], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "armed\n"
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the watcher did not end the program")
    print(f"swallowed Ctrl+C: ended {time.monotonic() - t0:.2f} s later")
    assert proc.returncode == 130
    assert err == "crane-collect: interrupted while compiling the control kernels; no torque was on\n"
