"""Standard errors for serially correlated data (train.evaluation.block_uncertainty): the stated 95 %
intervals of a least-squares fit with AR(1)-correlated regressors and noise cover the truth in about 95 %
of many independent data sets (a binomial tolerance), where the textbook covariance's do not; a repeated
stretch of data does not shrink them; the rigid-body model's standard errors and the diagnosis' jackknife
are this one estimator."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import binom

from train.evaluation.block_uncertainty import (
    block_count,
    jackknife_se,
    jackknife_values,
    least_squares_jackknife,
    repeated_rows,
    sample_blocks,
    t_factor,
)

RATE = 50.0  # Hz
TRUE = np.array([0.9, -0.4, 0.25])


def _ar1(rng, n, phi, size=()):
    """(n, *size) AR(1) series with unit marginal variance."""
    e = rng.normal(size=(n, *size))
    out = np.empty_like(e)
    out[0] = e[0]
    c = np.sqrt(1 - phi ** 2)
    for i in range(1, n):
        out[i] = phi * out[i - 1] + c * e[i]
    return out


def _data(rng, n=1500, phi=0.95):
    """A regression whose regressors and noise are both AR(1) with coefficient phi (a correlation time of
    ~20 rows, as filtered torque data have over a move)."""
    A = np.column_stack([np.ones(n), _ar1(rng, n, phi), _ar1(rng, n, phi)])
    b = A @ TRUE + 0.5 * _ar1(rng, n, phi)
    return A, b


def _naive_se(A, b):
    theta = np.linalg.lstsq(A, b, rcond=None)[0]
    r = b - A @ theta
    s2 = r @ r / (len(b) - A.shape[1])
    return theta, np.sqrt(np.diag(np.linalg.inv(A.T @ A)) * s2)


def _binomial_band(trials, p=0.95, alpha=0.002):
    """The counts of hits a correct p-interval gives with probability 1 - alpha."""
    return binom.ppf(alpha / 2, trials, p), binom.ppf(1 - alpha / 2, trials, p)


@pytest.fixture(scope="module")
def coverage():
    """Per parameter, how often the block jackknife's and the textbook covariance's 95 % intervals
    cover the truth over independent correlated data sets."""
    rng = np.random.default_rng(7)
    trials, hits, naive_hits = 200, np.zeros(3), np.zeros(3)
    for _ in range(trials):
        A, b = _data(rng)
        plan = sample_blocks(np.arange(len(b)), RATE)
        theta, naive = _naive_se(A, b)
        se = least_squares_jackknife(A, b, plan.ids, plan.count)
        hits += np.abs(theta - TRUE) <= t_factor(plan.count) * se
        naive_hits += np.abs(theta - TRUE) <= 1.96 * naive
    return trials, hits, naive_hits


def test_block_jackknife_intervals_cover_the_truth_at_their_level(coverage):
    trials, hits, _ = coverage
    lo, hi = _binomial_band(trials)
    assert np.all((hits >= lo) & (hits <= hi)), (hits / trials, lo / trials, hi / trials)


def test_the_textbook_covariance_is_too_tight_on_correlated_data(coverage):
    trials, _, naive_hits = coverage
    lo, _ = _binomial_band(trials)
    assert np.all(naive_hits[1:] < lo), naive_hits / trials


def _jackknife(A, b, check_repeats=True):
    plan = sample_blocks(np.arange(len(b)), RATE, np.column_stack([A, b]) if check_repeats else None)
    return plan, least_squares_jackknife(A, b, plan.ids, plan.count)


def test_a_repeated_recording_does_not_shrink_the_standard_error():
    rng = np.random.default_rng(3)
    A, b = _data(rng, n=1500)
    _, se = _jackknife(A, b)
    A2, b2 = np.vstack([A, A]), np.concatenate([b, b])  # the whole data set twice
    plan2, se2 = _jackknife(A2, b2)
    assert plan2.repeated == 1500 and np.all(plan2.ids[1500:] == plan2.ids[:1500])
    np.testing.assert_allclose(se2, se, rtol=1e-9)
    # counted as new evidence, the copies would shrink the errors by ~1/sqrt(2)
    assert np.all(_jackknife(A2, b2, check_repeats=False)[1] < 0.8 * se)


def test_a_repeated_stretch_joins_its_original_block():
    rng = np.random.default_rng(3)
    A, b = _data(rng, n=1500)
    plan, se = _jackknife(A, b)
    copy = slice(500, 1000)  # a third of the data, appended once more
    plan2, se2 = _jackknife(np.vstack([A, A[copy]]), np.concatenate([b, b[copy]]))
    assert plan2.repeated == 500 and plan2.count == plan.count
    assert np.all(plan2.ids[1500:] == plan2.ids[copy])
    # the copy re-weights the fit (its rows count twice) but adds no block of evidence
    assert np.all(se2 >= 0.75 * se), se2 / se


def test_blocks_are_contiguous_in_time_whatever_the_row_order():
    rng = np.random.default_rng(0)
    t = rng.permutation(600) / RATE  # 12 s of rows, shuffled
    plan = sample_blocks(t, RATE)
    assert plan.count == block_count(12.0) == 5
    order = np.argsort(t)
    assert np.all(np.diff(plan.ids[order]) >= 0)
    assert np.bincount(plan.ids).tolist() == [120] * 5


@pytest.mark.parametrize(("duration", "blocks"), [(6.0, 5), (30.0, 10), (60.0, 20), (600.0, 20)])
def test_block_count_keeps_blocks_of_seconds(duration, blocks):
    assert block_count(duration) == blocks


def test_repeated_rows_point_at_the_first_occurrence():
    v = np.array([[1.0, 2.0], [3.0, 4.0], [1.0, 2.0 + 1e-12], [-0.0, 5.0], [0.0, 5.0]])
    assert repeated_rows(v).tolist() == [0, 1, 0, 3, 3]


def test_jackknife_of_values_matches_the_formula():
    reps = np.array([1.0, 2.0, 4.0, 5.0])
    mean, se = jackknife_se(reps)
    assert mean == 3.0 and se == pytest.approx(np.sqrt(3 / 4 * 10.0))
    out = jackknife_values([{"k": v, "only_here": 1.0} if i == 0 else {"k": v} for i, v in enumerate(reps)])
    assert set(out) == {"k"} and out["k"] == pytest.approx((3.0, float(se)))
    assert t_factor(20) == pytest.approx(2.093, abs=1e-3)


def test_the_diagnosis_jackknife_is_the_same_estimator():
    from train.diagnosis.cv import jackknife

    folds = [{"k": 0.88}, {"k": 0.91}, {"k": 0.90}, {"k": 0.86}, {"k": 0.93}]
    assert jackknife(folds) == jackknife_values(folds)


# ---- the rigid-body model's standard errors ------------------------------------------------------------

@pytest.fixture(scope="module")
def rigid(tmp_path_factory):
    from tests.sessions import write_synthetic_session
    from train.data.preprocess import preprocess
    from train.data.session import read_sessions
    from train.models.registry import make_model

    path, _ = write_synthetic_session(tmp_path_factory.mktemp("blk") / "s.h5", 60, seed=2)
    ds = preprocess(read_sessions([path]))
    model = make_model("rigid-body", ds.joint_names, effects=[("coulomb", None, None)])
    return ds, model.fit(ds)


def test_the_rigid_body_standard_errors_are_the_block_jackknife(rigid):
    ds, model = rigid
    info = model.fit_info
    assert 5 <= info["stderr_blocks"] <= 20 and "jackknife" in info["stderr_method"]
    assert info["ci95_factor"] == pytest.approx(t_factor(info["stderr_blocks"]))
    assert np.all(np.isfinite(model.stderr)) and np.all(model.stderr > 0)
    # the fit's own equations, rows in blocks, give the same numbers through the estimator
    from train.models.rigid_body import fit_blocks

    rows = np.flatnonzero(ds.all_moving)
    sub = ds.subset(rows)
    plan = fit_blocks(sub)
    Phi = model.regressor(sub.q, sub.dq, sub.ddq, context=sub.context)
    scale = np.sqrt((Phi ** 2).mean(axis=(0, 1)))
    se = least_squares_jackknife((Phi / scale).reshape(-1, Phi.shape[2]), sub.tau.reshape(-1),
                                 np.repeat(plan.ids, Phi.shape[1]), plan.count, ridge=1 / model.p0) / scale
    np.testing.assert_allclose(model.stderr, se, rtol=1e-6)


def test_the_stderr_record_is_saved_and_checked_on_load(rigid, tmp_path):
    from train.models.base import ModelFileError
    from train.models.registry import load_model

    _, model = rigid
    model.save(tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert loaded.fit_info["stderr_blocks"] == model.fit_info["stderr_blocks"]
    np.testing.assert_array_equal(loaded.stderr, model.stderr)
    doc_path = tmp_path / "m" / "model.json"
    doc = json.loads(doc_path.read_text())
    state = doc["state"] if "state" in doc else doc
    state["fit_info"]["stderr_blocks"] = 0.5
    doc_path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="blocks"):
        load_model(tmp_path / "m")


def test_crane_train_fit_prints_the_effect_parameters_with_their_intervals(tmp_path):
    from click.testing import CliRunner

    from tests.sessions import write_synthetic_session
    from train.cli import main

    path, _ = write_synthetic_session(tmp_path / "s.h5", 60, seed=2)
    result = CliRunner().invoke(main, ["fit", str(path), "--model", "rigid-body", "--scale-to-data",
                                       "--effect", "coulomb:joint=joint2", "-o", str(tmp_path / "m")])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("effect parameters"))
    assert "jackknife" in lines[head] and "95 % interval" in lines[head]
    assert lines[head + 1].strip().startswith("values from zero-phase derivatives of the same samples")
    name, value, pm, se, low, high, loop, loop_value = lines[head + 2].translate(
        str.maketrans("[],", "   ")).split()
    assert name.startswith("coulomb.") and pm == "±" and loop == "loop"
    assert float(low) < float(value) < float(high) and float(se) > 0 and abs(float(loop_value)) > 0
