"""The hybrid's network share (train.models.hybrid_share): judged on out-of-fold network predictions,
chosen by cross-validation over time blocks, 0 when the network does not help out of sample, shrunk with
little data, capped on the validation data, and the hybrid not worse than its physics part on held-out
data when its network learnt nothing useful."""

from __future__ import annotations

import numpy as np
import pytest

from train.models.hybrid_share import MIN_ROWS, block_cv_share, cross_fit, validation_cap

RATE = 50.0


def _smooth(rng, n, width=25):
    """A slowly varying series (moving average of white noise over `width` rows), unit variance."""
    x = np.convolve(rng.normal(size=n + width), np.ones(width) / np.sqrt(width), mode="valid")[:n]
    return x / x.std()


def test_a_network_that_learnt_the_residual_gets_its_full_weight():
    rng = np.random.default_rng(0)
    r = _smooth(rng, 2000)
    share = block_cv_share(r, r + 0.1 * _smooth(rng, 2000), RATE)
    assert share.weight == pytest.approx(share.weight_all, rel=0.02) and share.weight > 0.9
    assert share.blocks == 13 and share.cv_gain > 0  # 40 s of rows: blocks of 3 s


@pytest.mark.parametrize("seed", range(6))
def test_a_network_unrelated_to_the_residual_gets_no_weight(seed):
    rng = np.random.default_rng(seed)
    r, m = _smooth(rng, 1500), _smooth(rng, 1500)  # slow noise: in-sample it often looks related
    share = block_cv_share(r, m, RATE)
    assert share.weight == 0.0, share


def test_too_few_validation_samples_use_the_physics_alone():
    rng = np.random.default_rng(1)
    r = _smooth(rng, MIN_ROWS - 1)
    share = block_cv_share(r, r, RATE)
    assert share.weight == 0.0 and "too few" in share.reason


def test_the_share_shrinks_with_little_data():
    """A network that explains a fifth of the residual's variance: with plenty of data (8 min) its share
    is near the least-squares weight; with little (6 s), the cross-validated gain is a smaller and less
    certain part of the in-sample gain and the share is smaller (or 0)."""
    def mean_share(n, trials=40):
        rng = np.random.default_rng(n)
        out = []
        for _ in range(trials):
            s, e = _smooth(rng, n), _smooth(rng, n)
            share = block_cv_share(0.45 * s + e, s, RATE)
            out.append((share.weight, share.weight_all))
        return np.array(out).mean(axis=0)

    big, small = mean_share(24000), mean_share(300)
    assert big[0] > 0.85 * big[1]
    assert small[0] < 0.6 * small[1]
    assert small[0] < big[0]


def test_the_share_is_a_least_squares_weight_between_0_and_1():
    rng = np.random.default_rng(2)
    r = _smooth(rng, 3000)
    assert block_cv_share(r, 0.5 * r, RATE).weight == 1.0  # would be 2: clipped
    assert block_cv_share(r, -r, RATE).weight == 0.0  # would be -1: clipped


def test_the_validation_cap_is_where_the_blend_stops_helping():
    r = np.array([1.0, 2.0, -1.0])
    m = np.array([0.5, 1.0, 0.0])
    cap = validation_cap(r, m)
    assert cap == pytest.approx(2 * 2.5 / 1.25)
    assert np.sum((r - cap * m) ** 2) == pytest.approx(np.sum(r ** 2))  # exactly as good as the physics
    assert validation_cap(r, -m) == 0.0 and validation_cap(r[:0], m[:0]) == float("inf")


class _Recorder:
    """A stand-in network: predicts, for every row, the earliest and latest time it was trained on."""

    def fit(self, ds, val):
        self.span = (float(np.min(ds.t)), float(np.max(ds.t)))
        return self

    def predict(self, q, dq, ddq):
        return np.tile(self.span, (len(q), 1))


def test_cross_fit_predicts_each_time_block_by_a_network_that_never_saw_it():
    from train.data.dataset import Dataset

    n = 90
    t = np.random.default_rng(0).permutation(n) / RATE  # rows shuffled, as a training pool's blocks are
    z = np.zeros((n, 2))
    ds = Dataset(("joint1", "joint2"), t, z, z, z, z, np.ones((n, 2), bool), RATE)
    first, last = cross_fit(_Recorder, ds, None, folds=3).T  # what each row's network was trained on
    block = np.argsort(np.argsort(t)) // 30  # each row's time block
    start, end = [t[block == k].min() for k in range(3)], [t[block == k].max() for k in range(3)]
    assert np.all(first[block == 0] == start[1]) and np.all(first[block > 0] == start[0])
    assert np.all(last[block == 2] == end[1]) and np.all(last[block < 2] == end[2])
    assert cross_fit(_Recorder, ds.subset(np.arange(5)), None, folds=3) is None


# ---- the hybrid model on held-out data ------------------------------------------------------------------

@pytest.fixture(scope="module")
def splits(tmp_path_factory):
    from tests.sessions import write_synthetic_session
    from train.data.preprocess import preprocess
    from train.data.session import read_sessions
    from train.data.splits import SplitConfig, make_splits

    path, _ = write_synthetic_session(tmp_path_factory.mktemp("share") / "s.h5", 90, seed=5)
    ds = preprocess(read_sessions([path]))
    return make_splits(ds, SplitConfig(n_pool=600, n_val=250, n_test=250), seed=0)


@pytest.fixture(scope="module")
def noisy(splits):
    """A hybrid whose physics part has the session's friction (nothing is left for a network) and whose
    network, one epoch at a high learning rate, learnt noise that makes physics + network worse."""
    from train.models.registry import make_model

    effects = [("coulomb", None, None), ("viscous", None, None)]
    return make_model("hybrid", splits.pool.joint_names, effects=effects, epochs=1, lr=0.05, batch_size=64,
                      seed=1).fit(splits.pool, splits.val)


def test_a_network_that_learnt_noise_leaves_the_hybrid_no_worse_than_its_physics_on_held_out_data(splits,
                                                                                                   noisy):
    from train.evaluation.metrics import mse

    test = splits.test
    physics = mse(test.tau, noisy.rigid.predict_dataset(test))
    hybrid = mse(test.tau, noisy.predict_dataset(test))
    assert np.all(hybrid <= 1.02 * physics), (hybrid / physics, noisy.network_weight)
    shares = noisy.blend_info["share"]
    assert set(shares) == set(splits.pool.joint_names)
    assert all(s["blocks"] >= 2 and isinstance(s["reason"], str) for s in shares.values())


def test_a_damaged_share_record_is_refused_on_load(noisy, tmp_path):
    import json

    from train.models.base import ModelFileError
    from train.models.registry import load_model

    noisy.save(tmp_path / "m")
    assert load_model(tmp_path / "m").blend_info["share"] == json.loads(json.dumps(noisy.blend_info["share"]))
    doc_path = tmp_path / "m" / "model.json"
    doc = json.loads(doc_path.read_text())
    doc["state"]["blend"]["share"]["joint1"]["weight_all"] = 2.0
    doc_path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="share"):
        load_model(tmp_path / "m")


def test_a_network_that_overshoots_where_the_physics_is_good_keeps_those_stretches_within_2_percent():
    """The physics part is 7 times better (in amplitude) in one 3 s stretch of four (a spring's joint near
    its rest angle), and the network's own error is the same everywhere: there it is larger than the
    physics' error. The pooled least-squares weight makes those stretches of new data much worse than the
    physics alone; the share, chosen with every block counting alike, keeps them within 2 % and still
    removes most of the error elsewhere."""
    def draw(seed, n=3000):
        rng = np.random.default_rng(seed)
        good = (np.arange(n) // int(3 * RATE)) % 4 == 3
        r = _smooth(rng, n) * np.where(good, 0.15, 1.0)
        return r, r + 0.2 * _smooth(rng, n), good

    share = block_cv_share(*draw(0)[:2], RATE)
    r, m, good = draw(1)

    def ratio(w, rows):
        return np.sum((r[rows] - w * m[rows]) ** 2) / np.sum(r[rows] ** 2)

    assert ratio(share.weight_all, good) > 1.3  # the pooled weight
    assert ratio(share.weight, good) <= 1.02, (share, ratio(share.weight, good))
    assert ratio(share.weight, ~good) < 0.5
