"""`--help` of both command lines and of every subcommand imports none of the heavy libraries (torch,
h5py, pinocchio, scipy, matplotlib): help must come back at once, even on a loaded machine. Each check runs
in a fresh interpreter so that other tests' imports cannot hide (or cause) a heavy import."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

HEAVY = ("torch", "h5py", "pinocchio", "scipy", "matplotlib", "rerun")

PROBE = textwrap.dedent("""
    import importlib, json, sys
    from click.testing import CliRunner
    heavy = {heavy!r}
    main = importlib.import_module({module!r}).main
    runner = CliRunner()
    report = []
    for args in [["--help"]] + [[name, "--help"] for name in main.list_commands(None)]:
        result = runner.invoke(main, args)
        loaded = sorted(h for h in heavy if h in sys.modules)
        report.append({{"args": args, "exit": result.exit_code, "loaded": loaded,
                        "usage": result.output.startswith("Usage:")}})
    print(json.dumps(report))
""")


def help_imports(module: str) -> list[dict]:
    code = PROBE.format(heavy=HEAVY, module=module)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.parametrize("module", ["train.cli", "collect.cli"])
def test_help_imports_no_heavy_library(module):
    report = help_imports(module)
    assert len(report) > 1  # the group's help and at least one subcommand's
    for row in report:
        assert row["exit"] == 0 and row["usage"], row
        assert row["loaded"] == [], f"{module} {' '.join(row['args'])} imported {row['loaded']}"


def test_train_help_lists_every_subcommand():
    names = [row["args"][0] for row in help_imports("train.cli")[1:]]
    assert names == sorted(["info", "fit", "identify", "sweep", "report", "diagnose", "compare", "effects",
                            "export", "fidelity", "view", "import"])


def test_light_method_names_match_the_registry_and_the_sweep():
    from train.evaluation import sweep
    from train.models.method_names import METHOD_NAMES, SWEEP_METHODS
    from train.models.registry import METHODS

    assert tuple(METHODS) == METHOD_NAMES
    assert sweep.SWEEP_METHODS == SWEEP_METHODS and set(SWEEP_METHODS) <= set(METHOD_NAMES)


def test_diagnose_keeps_its_defaults():
    from train.diagnosis import diagnose
    from train.diagnosis.defaults import DEFAULT_FOLDS, DEFAULT_MIN_REDUCTION

    assert (diagnose.DEFAULT_FOLDS, diagnose.DEFAULT_MIN_REDUCTION) == (DEFAULT_FOLDS, DEFAULT_MIN_REDUCTION)


def test_crane_ios_library_modules_import_no_command_line_library():
    """The command line lives at the edge: only crane_io.cli_support (shared by both CLIs) may import
    click; every other crane_io module imports without it."""
    import pkgutil

    import crane_io

    names = [m.name for m in pkgutil.walk_packages(crane_io.__path__, "crane_io.")
             if m.name != "crane_io.cli_support"]
    code = ("import importlib, sys\n"
            f"for name in {names!r}:\n"
            "    importlib.import_module(name)\n"
            "print('click' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False", "a crane_io library module imports click"


BLAS_PROBE = textwrap.dedent("""
    import importlib, json
    importlib.import_module({module!r})
    import numpy  # noqa: F401  (the commands import it after the command line module)
    from threadpoolctl import threadpool_info
    print(json.dumps([i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]))
""")


@pytest.mark.parametrize("module", ["train.cli", "collect.cli"])
@pytest.mark.parametrize("env, expected", [({}, 1), ({"OPENBLAS_NUM_THREADS": "2"}, 2)])
def test_the_commands_run_numpy_on_one_blas_thread_unless_told_otherwise(module, env, expected):
    """OpenBLAS's spinning threads made diagnose several times slower in CPU on a busy machine; the
    command lines ask for one thread, and a user's OPENBLAS_NUM_THREADS wins."""
    import os

    full = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"} | env
    out = subprocess.run([sys.executable, "-c", BLAS_PROBE.format(module=module)], env=full,
                         capture_output=True, text=True, check=True)
    threads = json.loads(out.stdout.strip().splitlines()[-1])
    assert threads and all(t == min(expected, os.cpu_count() or expected) for t in threads)


FIT_PROBE = textwrap.dedent("""
    import json, sys
    from click.testing import CliRunner
    from train.cli import main
    result = CliRunner().invoke(main, sys.argv[1:])
    print(json.dumps({"exit": result.exit_code, "output": result.output[-400:],
                      "torch": "torch" in sys.modules}))
""")


def test_a_rigid_body_fit_and_its_diagnosis_never_import_torch(tmp_path):
    """torch takes 1.5-4 s to import; only the networks need it."""
    from tests.sessions import write_synthetic_session

    session, _ = write_synthetic_session(tmp_path / "s.h5", 60, seed=3)
    model = tmp_path / "rb"
    for args in (["fit", str(session), "--model", "rigid-body", "-o", str(model), "--scale-to-data",
                  "--no-progress"],
                 ["diagnose", str(model), str(session)]):
        out = subprocess.run([sys.executable, "-c", FIT_PROBE, *args], capture_output=True, text=True,
                             check=True)
        report = json.loads(out.stdout.strip().splitlines()[-1])
        assert report["exit"] == 0, report["output"]
        assert not report["torch"], args[0]
