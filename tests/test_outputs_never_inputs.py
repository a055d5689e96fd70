"""Every command that writes a file checks its output first (crane_io.output_files): an output that is
one of the command's inputs (named directly, through a symbolic link or a hard link) is refused in one
sentence with exit 2 even with --force, and the input keeps its bytes; an existing output is refused
without --force and replaced with it."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from collect.cli import main as collect_main
from tests.sessions import write_synthetic_session
from train.cli import main as train_main

LINKS = ["same", "symlink", "hardlink"]
EXAMPLE_EFFECT = Path(__file__).parents[1] / "docs" / "examples" / "cable_drag.json"
MAP = ["--map", "t=time", "--map", "joint1.q=q1,joint1.tau=tau1"]
RUN_CONFIG = "[loop]\nstatus_hz = 0\n[operator.start_deg]\njoint2 = 0.0\njoint4 = -20.0\n"


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A session, a rigid-body model fitted on it, a CSV log and a run configuration (read-only inputs)."""
    d = tmp_path_factory.mktemp("outputs")
    session, _ = write_synthetic_session(d / "s.h5", 60, seed=5)
    model = d / "model"
    r = CliRunner().invoke(train_main, ["fit", str(session), "--model", "rigid-body", "--scale-to-data",
                                        "--no-progress", "-o", str(model)])
    assert r.exit_code == 0, r.output
    t = np.arange(200) / 100.0
    (d / "log.csv").write_text("time,q1,tau1\n" + "".join(f"{a},{np.sin(a)},{np.cos(a)}\n" for a in t))
    (d / "run.toml").write_text(RUN_CONFIG)
    (d / "effect.json").write_text(EXAMPLE_EFFECT.read_text())
    return d


def _digest(paths) -> dict:
    out = {}
    for p in paths:
        p = Path(p)
        for f in ([p] if p.is_file() else sorted(p.rglob("*"))):
            if f.is_file():
                out[f] = f.read_bytes()
    return out


def _alias(path: Path, how: str, folder: Path, suffix: str | None = None) -> Path:
    """`path` itself, or a new symbolic or hard link to it in `folder` (ending in `suffix`)."""
    if how == "same":
        return path
    alias = folder / f"alias-{how}{path.suffix if suffix is None else suffix}"
    if how == "symlink":
        alias.symlink_to(path)
    else:
        os.link(path, alias)
    return alias


def _invoke(main, args, **kw):
    return CliRunner().invoke(main, [str(a) for a in args], **kw)


def _refused(r, *words):
    assert r.exit_code == 2, r.output
    assert r.output.startswith("Error: ") and r.output.count("\n") == 1, r.output
    assert "Traceback" not in r.output
    for w in words:
        assert w in r.output, r.output


def _train_commands(lab: Path, out: Path) -> dict:
    """Each crane-train command that writes, with `out` in the place of its output, and its input that
    `out` names."""
    session, model, effect = lab / "s.h5", lab / "model", lab / "effect.json"
    return {
        "report": (["report", model, session, "-o", out], session),
        "diagnose --json-out": (["diagnose", model, session, "--json-out", out], session),
        "diagnose --write-effect-file": (["diagnose", model, session, "--effect-file", effect,
                                          "--write-effect-file", out], effect),
        "compare -o": (["compare", model, "--session", session, "-o", out], session),
        "fit -o": (["fit", session, "--model", "rigid-body", "--scale-to-data", "-o", out], session),
        "import -o": (["import", lab / "log.csv", "-o", out, *MAP], lab / "log.csv"),
        "view --view-save": (["view", session, "--view-save", out], session),
    }


TRAIN_CASES = [(command, how) for command in ["report", "diagnose --json-out", "diagnose --write-effect-file",
                                              "compare -o", "fit -o", "import -o", "view --view-save"]
               for how in LINKS
               if (command, how) != ("compare -o", "same")]  # a plot is .png: a session through a link


@pytest.mark.parametrize("command, how", TRAIN_CASES)
def test_a_train_output_that_is_an_input_is_refused_even_with_force(lab, tmp_path, command, how):
    suffix = {"compare -o": ".png", "diagnose --write-effect-file": ".json"}.get(command)
    _, target = _train_commands(lab, tmp_path)[command]
    out = _alias(target, how, tmp_path, suffix)
    args, _ = _train_commands(lab, out)[command]
    before = _digest([lab])
    _refused(_invoke(train_main, [*args, "--force"]), "same file as the input")
    assert _digest([lab]) == before


@pytest.mark.parametrize("how", ["symlink", "hardlink"])
def test_sweep_refuses_a_result_file_that_is_its_session(lab, tmp_path, how):
    out = tmp_path / "sweep"
    out.mkdir()
    link = _alias(lab / "s.h5", how, out, ".json")
    link.rename(out / "results.json")
    before = _digest([lab])
    r = _invoke(train_main, ["sweep", lab / "s.h5", "-o", out, "--sizes", "50", "--trials", "2", "--force"])
    _refused(r, "same file as the input")
    assert _digest([lab]) == before


def test_a_model_folder_holding_the_session_or_a_foreign_folder_is_never_replaced(lab, tmp_path):
    shutil.copy(lab / "s.h5", tmp_path / "s.h5")
    fit = ["fit", tmp_path / "s.h5", "--model", "rigid-body", "--scale-to-data", "--force", "-o"]
    _refused(_invoke(train_main, [*fit, tmp_path]), "holds the input")
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "todo.txt").write_text("keep")
    _refused(_invoke(train_main, [*fit, notes]), "holds no model")
    assert (notes / "todo.txt").read_text() == "keep" and (tmp_path / "s.h5").read_bytes() == (
        lab / "s.h5").read_bytes()


def test_export_refuses_a_loop_export_that_is_one_of_the_models_files(lab, tmp_path):
    model = tmp_path / "model"
    shutil.copytree(lab / "model", model)
    (model / "loop_model.npz").unlink()
    os.link(model / "model.json", model / "loop_model.npz")
    before = _digest([model])
    _refused(_invoke(train_main, ["export", model, "--force"]), "same file as the input")
    assert _digest([model]) == before


@pytest.mark.parametrize("how", LINKS)
def test_recover_never_writes_over_the_session_it_reads(lab, tmp_path, how):
    session = tmp_path / "s.h5"
    shutil.copy(lab / "s.h5", session)
    out = _alias(session, how, tmp_path)
    before = session.read_bytes()
    _refused(_invoke(collect_main, ["recover", session, "-o", out, "--force"]), "same file as the input")
    assert session.read_bytes() == before


@pytest.mark.parametrize("how", LINKS)
@pytest.mark.parametrize("case", ["-o is --config", "--truth is --config", "--truth-trace is -o",
                                  "--truth is -o", "--view-save is -o"])
def test_run_refuses_outputs_that_are_inputs_or_each_other_before_anything_starts(lab, tmp_path, case, how):
    if "--view-save" in case:
        pytest.importorskip("rerun")
    config = tmp_path / "run.toml"
    shutil.copy(lab / "run.toml", config)
    session = tmp_path / "s.h5"
    session.write_bytes(b"an earlier session")  # --force may replace it; a hard link needs a file
    alias = _alias(config if "--config" in case else session, how, tmp_path)
    flag = case.split()[0]
    base = ["run", "--sim", "--plant", "simple", "--duration", "0.1", "--config", config, "--force"]
    args = [*base, "-o", alias] if flag == "-o" else [*base, "-o", session, flag, alias]
    before = _digest([tmp_path])
    r = _invoke(collect_main, args)
    _refused(r, "same file as the input" if "--config" in case else "another output")
    assert _digest([tmp_path]) == before
    assert "aligning" not in r.output


@pytest.mark.parametrize("how", ["same", "symlink"])
def test_calibrate_never_writes_over_its_port(tmp_path, how):
    port = tmp_path / "port"
    port.write_bytes(b"not a calibration")
    out = _alias(port, how, tmp_path, ".toml")
    r = _invoke(collect_main, ["calibrate", "--port", port, "--arm", "a", "--output", out, "--force"])
    _refused(r, "same file as the input")
    assert port.read_bytes() == b"not a calibration"


def test_sim_serve_truth_never_writes_over_its_configuration(lab, tmp_path):
    config = tmp_path / "run.toml"
    shutil.copy(lab / "run.toml", config)
    r = _invoke(collect_main, ["sim-serve", "--pair", "--leader-link", tmp_path / "l", "--follower-link",
                               tmp_path / "f", "--config", config, "--truth", config, "--force"])
    _refused(r, "same file as the input")
    assert config.read_text() == RUN_CONFIG


# ---- an existing output: refused without --force, replaced with it -------------------------------------

def _train_writers(lab: Path, out: Path) -> dict:
    """crane-train commands whose one output is `out` (a file), with fast settings."""
    session, model = lab / "s.h5", lab / "model"
    return {
        "report": ["report", model, session, "-o", out, "--no-diagnosis"],
        "diagnose --json-out": ["diagnose", model, session, "--json-out", out, "--folds", "2"],
        "compare -o": ["compare", model, "--session", session, "-o", out],
        "import -o": ["import", lab / "log.csv", "-o", out, *MAP],
        "view --view-save": ["view", session, "--view-save", out, "--every", "50"],
    }


@pytest.mark.parametrize("command, name", [("report", "r.html"), ("diagnose --json-out", "d.json"),
                                           ("compare -o", "c.png"), ("import -o", "i.h5"),
                                           ("view --view-save", "v.rrd")])
def test_an_existing_train_output_needs_force(lab, tmp_path, command, name):
    if command == "view --view-save":
        pytest.importorskip("rerun")
    out = tmp_path / name
    out.write_bytes(b"old")
    args = _train_writers(lab, out)[command]
    _refused(_invoke(train_main, args), "already exists", "--force")
    assert out.read_bytes() == b"old"
    r = _invoke(train_main, [*args, "--force"])
    assert r.exit_code == 0, r.output
    assert out.read_bytes() != b"old" and out.stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # no temporary file left


def test_fit_replaces_an_existing_model_folder_whole_only_with_force(lab, tmp_path):
    out = tmp_path / "m"
    shutil.copytree(lab / "model", out)
    (out / "stale.txt").write_text("from the old model")
    fit = ["fit", lab / "s.h5", "--model", "rigid-body", "--scale-to-data", "--seed", "3", "-o", out]
    _refused(_invoke(train_main, fit), "already exists", "--force")
    assert (out / "stale.txt").exists()
    r = _invoke(train_main, [*fit, "--force"])
    assert r.exit_code == 0, r.output
    assert not (out / "stale.txt").exists()  # replaced whole
    assert json.loads((out / "fit_metrics.json").read_text())["seed"] == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m"]


def test_sweep_into_a_folder_refuses_its_existing_result_files_without_force(lab, tmp_path):
    out = tmp_path / "sweep"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "results.csv").write_text("old")
    sweep = ["sweep", lab / "s.h5", "-o", out, "--sizes", "50", "--trials", "2", "--methods", "rigid-body",
             "--scale-to-data", "--no-progress"]
    _refused(_invoke(train_main, sweep), "results.csv already exists", "--force")
    assert (out / "results.csv").read_text() == "old"
    r = _invoke(train_main, [*sweep, "--force"])
    assert r.exit_code == 0, r.output
    assert (out / "results.csv").read_text().startswith("method,size")
    assert (out / "notes.txt").read_text() == "mine"  # the folder's other files stay
    assert sorted(p.name for p in out.iterdir()) == ["mse_vs_samples.png", "notes.txt", "results.csv",
                                                     "results.json", "window_torque.png"]


def test_export_replaces_an_existing_loop_export_only_with_force(lab, tmp_path):
    model = tmp_path / "model"
    shutil.copytree(lab / "model", model)
    before = _digest([model])
    r = _invoke(train_main, ["export", model])
    _refused(r, "loop_model.npz already exists", "--force")
    assert _digest([model]) == before
    r = _invoke(train_main, ["export", model, "--force"])
    assert r.exit_code == 0, r.output
    assert _digest([model]) == before  # the same model gives the same bytes


def test_run_truth_is_not_overwritten_without_force(lab, tmp_path):
    truth = tmp_path / "t.json"
    truth.write_text("old")
    base = ["run", "--sim", "--plant", "hidden-coulomb", "--duration", "0.1", "--config", lab / "run.toml",
            "--quiet", "--truth", truth]
    _refused(_invoke(collect_main, [*base, "-o", tmp_path / "a.h5"]), "already exists", "--force")
    assert truth.read_text() == "old" and not (tmp_path / "a.h5").exists()
    r = _invoke(collect_main, [*base, "-o", tmp_path / "a.h5", "--force"])
    assert r.exit_code == 0, r.output
    assert json.loads(truth.read_text())["hidden"]["effect"] == "coulomb"


def test_recover_output_needs_force_and_compare_refuses_a_plot_that_is_no_image(lab, tmp_path):
    out = tmp_path / "r.h5"
    out.write_bytes(b"old")
    _refused(_invoke(collect_main, ["recover", lab / "s.h5", "-o", out]), "already exists", "--force")
    assert out.read_bytes() == b"old"
    _refused(_invoke(train_main, ["compare", lab / "model", "-o", tmp_path / "c.txt"]), "not .txt")
    assert not (tmp_path / "c.txt").exists()


def test_an_existing_effect_file_is_refused_without_force_before_any_work(lab, tmp_path):
    out = tmp_path / "found.json"
    out.write_text("# mine")
    r = _invoke(train_main, ["diagnose", lab / "model", lab / "s.h5", "--write-effect-file", out])
    _refused(r, "already exists", "--force")
    assert out.read_text() == "# mine"


def test_recover_replaces_an_existing_output_only_with_force(tmp_path):
    from tests.test_recover import _crashed

    crashed = _crashed(tmp_path / "s.h5")
    before = crashed.read_bytes()
    out = tmp_path / "r.h5"
    out.write_bytes(b"old")
    _refused(_invoke(collect_main, ["recover", crashed, "-o", out]), "already exists", "--force")
    assert out.read_bytes() == b"old"
    r = _invoke(collect_main, ["recover", crashed, "-o", out, "--force"])
    assert r.exit_code == 0, r.output
    assert out.read_bytes()[:8] == b"\x89HDF\r\n\x1a\n" and crashed.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.h5", "s.h5"]


def test_calibrate_output_needs_force(tmp_path):
    out = tmp_path / "c.toml"
    out.write_text("old")
    r = _invoke(collect_main, ["calibrate", "--port", tmp_path / "no-port", "--arm", "a", "--output", out])
    _refused(r, "already exists", "--force")
    assert out.read_text() == "old"


def test_the_python_front_door_checks_its_outputs_too(lab, tmp_path):
    import train
    from crane_io.output_files import OutputPathError
    from train.data.importer import ImportUnits, import_session, parse_map

    before = _digest([lab])
    with pytest.raises(OutputPathError, match="same file as the input"):
        train.make_report(lab / "model", lab / "s.h5", _alias(lab / "s.h5", "symlink", tmp_path))
    with pytest.raises(OutputPathError, match="same file as the input"):
        import_session(lab / "log.csv", lab / "log.csv", parse_map(["t=time", "joint1.q=q1,joint1.tau=tau1"]),
                       ImportUnits(), force=True)
    fitted = train.fit(lab / "s.h5", "rigid-body", scale_to_data=True)
    fitted.save(tmp_path / "m")
    with pytest.raises(OutputPathError, match="already exists"):
        fitted.save(tmp_path / "m")
    assert fitted.save(tmp_path / "m", force=True) == tmp_path / "m"
    with pytest.raises(OutputPathError, match="holds the input"):
        fitted.save(lab, force=True)
    assert _digest([lab]) == before
