"""crane-train compare: successive models scored on the same held-out samples, table + plot + JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from tests.fitting import fit_model
from tests.sessions import write_synthetic_session
from train.cli import main
from train.data.preprocess import preprocess
from train.data.session import read_sessions
from train.data.splits import make_splits
from train.evaluation.compare import Comparison, ModelScore, compare_models, legend_names, plot, table_text
from train.evaluation.heldout import evaluation_data
from train.evaluation.plots import change_text, comparison_figure
from train.models.registry import load_model


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """Two models fitted by `crane-train fit`'s code path on one session: rigid-body without and with
    the session's friction."""
    root = tmp_path_factory.mktemp("cmp")
    session, _ = write_synthetic_session(root / "s.h5", 150, seed=7)
    dirs = []
    for name, effects in (("rb", []), ("rb-friction", [("coulomb", None, None), ("viscous", None, None)])):
        fit_model([str(session)], "rigid-body", root / name, seed=2, effects=effects, scale_to_data=True,
                  progress=False)
        dirs.append(root / name)
    ds = preprocess(read_sessions([session]))
    return session, dirs, make_splits(ds, seed=2, scale_to_data=True)


def test_models_are_scored_on_the_same_held_out_samples(fitted):
    session, dirs, sp = fitted
    c = compare_models(dirs, [session])
    assert [m.method for m in c.models] == ["rigid-body", "rigid-body"]
    assert c.models[1].effects == ["coulomb", "viscous"]
    assert c.models[0].n_test == c.models[1].n_test == len(sp.index["test"])
    # the test metric equals the model's error on the split's own test set
    m1 = load_model(dirs[1])
    err = ((sp.test.tau - m1.predict_dataset(sp.test)) ** 2).mean(axis=0)
    np.testing.assert_allclose([c.models[1].test["mse"][j] for j in c.joints], err, rtol=1e-9)
    # the friction the session holds: adding it makes every joint's error fall
    for j in c.joints:
        assert c.models[1].test["mse"][j] < 0.5 * c.models[0].test["mse"][j]
    text = table_text(c)
    assert "rb-friction" in text and "%" in text


def test_held_out_data_follow_the_models_recorded_split(fitted):
    session, dirs, sp = fitted
    _, splits, held = evaluation_data(load_model(dirs[0]), [session], model_dir=dirs[0])
    np.testing.assert_array_equal(splits.index["test"], sp.index["test"])
    assert held.test.sum() == len(sp.index["test"])


def test_compare_cli_json_and_plot(fitted, tmp_path):
    session, dirs, _ = fitted
    out = tmp_path / "cmp.png"
    r = CliRunner().invoke(main, ["compare", *map(str, dirs), "--session", str(session), "--json",
                                  "-o", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert [m["directory"] for m in doc["models"]] == [str(d) for d in dirs]
    assert set(doc["models"][0]["test"]) == {"mse", "rmse", "nmse"}
    assert out.stat().st_size > 5000 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = CliRunner().invoke(main, ["compare", *map(str, dirs), "--session", str(session)])
    assert r.exit_code == 0 and "joint2 MSE" in r.output


def test_compare_bad_input_is_one_sentence(fitted, tmp_path):
    session, dirs, _ = fitted
    r = CliRunner().invoke(main, ["compare", str(tmp_path / "nope"), "--session", str(session)])
    assert r.exit_code != 0 and r.output.startswith("Error: ") and "Traceback" not in r.output
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    r = CliRunner().invoke(main, ["compare", str(dirs[0]), "--session", str(bad)])
    assert r.exit_code != 0 and r.output.startswith("Error: ")


def test_sessions_default_to_the_ones_the_model_was_trained_on(fitted):
    _, dirs, sp = fitted
    c = compare_models(dirs)
    assert c.models[0].n_test == len(sp.index["test"])


def test_plot_writes_a_png(fitted, tmp_path):
    session, dirs, _ = fitted
    path = plot(compare_models(dirs, [session]), tmp_path / "p.png")
    assert path.exists() and path.stat().st_size > 5000


def _texts(ax):
    return [t.get_text() for t in ax.texts]


def test_plot_groups_one_bar_per_model_by_joint_on_a_log_axis(fitted):
    import matplotlib.pyplot as plt

    session, dirs, _ = fitted
    c = compare_models(dirs, [session])
    fig = comparison_figure(c)
    try:
        (ax,) = fig.axes
        assert ax.get_yscale() == "log"
        assert "MSE" in ax.get_ylabel()
        # joints on the x axis, one bar per (model, joint), one colour per model in every group
        assert [t.get_text() for t in ax.get_xticklabels()] == list(c.joints)
        assert len(ax.containers) == len(c.models)
        assert len(ax.patches) == len(c.models) * len(c.joints)
        colours = [{bar.get_facecolor() for bar in bars} for bars in ax.containers]
        assert all(len(k) == 1 for k in colours) and len(set.union(*colours)) == len(c.models)
        for bars, s in zip(ax.containers, c.models):
            np.testing.assert_allclose([b.get_height() for b in bars], [s.test["mse"][j] for j in c.joints])
        # the bars of one joint sit around that joint's tick, the models in the given order
        for k in range(len(c.joints)):
            xs = [bars[k].get_x() + bars[k].get_width() / 2 for bars in ax.containers]
            assert xs == sorted(xs) and abs(np.mean(xs) - k) < 1e-9
        assert ax.get_lines() == []  # no line across the bars of unrelated models
        # the legend names every model by its directory, method and what it adds
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert legend == ["1. rb: rigid-body", "2. rb-friction: rigid-body +coulomb +viscous"]
        # the change against the first model above each later bar
        base, other = c.models
        for j in c.joints:
            assert change_text(other.test["mse"][j], base.test["mse"][j]) in _texts(ax)
        assert _texts(ax).count("ref") == len(c.joints)
        assert str(base.n_test) in fig._suptitle.get_text() and "MSE" in fig._suptitle.get_text()
    finally:
        plt.close(fig)


def test_plot_and_cli_follow_the_chosen_metric(fitted, tmp_path):
    import matplotlib.pyplot as plt

    session, dirs, _ = fitted
    c = compare_models(dirs, [session])
    fig = comparison_figure(c, "rmse")
    try:
        ax = fig.axes[0]
        assert "RMSE" in ax.get_ylabel() and "RMSE" in fig._suptitle.get_text()
        np.testing.assert_allclose([b.get_height() for b in ax.containers[1]],
                                   [c.models[1].test["rmse"][j] for j in c.joints])
    finally:
        plt.close(fig)
    out = tmp_path / "rmse.png"
    r = CliRunner().invoke(main, ["compare", *map(str, dirs), "--session", str(session), "--metric", "rmse",
                                  "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "joint2 RMSE" in r.output and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _score(directory, effects, values, joints=("joint1", "joint2")):
    table = dict(zip(joints, values))
    return ModelScore(directory, "rigid-body", effects, {"mse": table, "rmse": table, "nmse": table}, {}, 40)


def test_plot_keeps_tiny_and_missing_errors_visible():
    import matplotlib.pyplot as plt

    base = ["coulomb:joint=joint1"]
    c = Comparison(("joint1", "joint2"), [
        _score("a/baseline", base, [0.02, 0.3]),
        _score("a/better", [*base, "coulomb:joint=joint2"], [0.0008, 0.0012]),  # -96 %, -99.6 %
        _score("b/better", [], [0.0, float("nan")]),
    ], "test")
    fig = comparison_figure(c)
    try:
        ax = fig.axes[0]
        lo, hi = ax.get_ylim()
        # every positive error lies well inside the log axis: the -99.6 % bar is no sliver
        assert lo <= 0.0008 / 2 and hi >= 0.3
        assert {"-96%", "-99.6%", "-100%", "n/a"} <= set(_texts(ax))
        assert all(t.get_text() for t in ax.yaxis.get_majorticklabels() if lo <= t.get_position()[1] <= hi)
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        # the same directory name twice: its parent tells them apart
        assert legend == ["1. baseline: rigid-body, 1 effect", "2. a/better: rigid-body +coulomb(joint2)",
                          "3. b/better: rigid-body -coulomb(joint1)"]
    finally:
        plt.close(fig)


def test_legend_names_are_short():
    many = [f"effect{k}:joint=joint1" for k in range(6)]
    c = Comparison(("joint1", "joint2"), [_score("models/" + "x" * 80, [], [1, 1]),
                                          _score("models/more", many, [1, 1])], "test")
    first, second = legend_names(c)
    assert len(first.split(": ")[0]) == len("1. ") + 30 and first.startswith("1. xxx") and "\u2026" in first
    assert second == "2. more: rigid-body +effect0(joint1) +effect1(joint1) and 4 more"
    assert change_text(1.0, 0.0) == "" and change_text(float("nan"), 1.0) == ""
    assert change_text(2.0, 1.0) == "+100%" and change_text(0.9, 1.0) == "-10%"
