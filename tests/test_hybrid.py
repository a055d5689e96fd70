"""The hybrid model: physics with chosen effects plus a masked network on its residual."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.sessions import write_synthetic_session
from train.data.preprocess import preprocess
from train.data.session import read_sessions
from train.data.splits import SplitConfig, make_splits
from train.evaluation.metrics import mse
from train.models.registry import load_model, make_model

FAST = {"epochs": 8, "batch_size": 64, "seed": 0}


@pytest.fixture(scope="module")
def splits(tmp_path_factory):
    path, _ = write_synthetic_session(tmp_path_factory.mktemp("hyb") / "s.h5", 150, seed=4)
    ds = preprocess(read_sessions([path]))
    return make_splits(ds, SplitConfig(n_pool=1500, n_val=250, n_test=250), seed=0)


@pytest.fixture(scope="module")
def hybrid(splits):
    return make_model("hybrid", splits.pool.joint_names, **FAST).fit(splits.pool, splits.val)


def test_hybrid_is_physics_plus_network_on_its_residual(splits, hybrid):
    rigid = make_model("rigid-body", splits.pool.joint_names).fit(splits.pool, splits.val)
    test = splits.test
    # the physics part is exactly the rigid-body model fitted alone
    np.testing.assert_allclose(hybrid.rigid.predict_dataset(test), rigid.predict_dataset(test), atol=1e-9)
    np.testing.assert_allclose(hybrid.predict_dataset(test),
                               hybrid.rigid.predict_dataset(test) + hybrid.mlp.predict_dataset(test))
    assert hybrid.mlp.method == "mlp-masked"
    # the session has Coulomb and viscous friction that the plain rigid-body model lacks: the network
    # on the residual learns much of it
    before = mse(test.tau, rigid.predict_dataset(test))
    after = mse(test.tau, hybrid.predict_dataset(test))
    assert np.all(after < 0.6 * before), (before, after)


def test_hybrid_takes_effects_for_its_physics_part(splits):
    model = make_model("hybrid", splits.pool.joint_names, effects=[("coulomb", "joint2", None)], **FAST)
    model.fit(splits.pool, splits.val)
    names = [row["name"] for row in model.parameters_table()]
    assert any(n.startswith("coulomb.") and "joint2" in n for n in names), names


def test_hybrid_save_load_round_trip(tmp_path, splits, hybrid):
    hybrid.save(tmp_path / "m")
    doc = json.loads((tmp_path / "m" / "model.json").read_text())
    assert doc["method"] == "hybrid"
    loaded = load_model(tmp_path / "m")
    assert loaded.method == "hybrid"
    np.testing.assert_array_equal(loaded.predict_dataset(splits.test), hybrid.predict_dataset(splits.test))


def test_hybrid_part_missing_is_a_clear_error(tmp_path, hybrid):
    import shutil

    from crane_io.errors import CraneError

    hybrid.save(tmp_path / "m")
    shutil.rmtree(tmp_path / "m" / "mlp")
    with pytest.raises(CraneError, match="model"):
        load_model(tmp_path / "m")


def test_the_hybrid_is_never_worse_than_its_physics_part_on_validation(splits):
    """A network that learnt little but noise (one epoch at a high learning rate, on the residual of a
    physics part that already has the session's friction) made the plain sum physics + network worse
    than the physics alone. Its share is chosen per joint on the validation data: never worse there."""
    effects = [("coulomb", None, None), ("viscous", None, None)]
    model = make_model("hybrid", splits.pool.joint_names, effects=effects, epochs=1, lr=0.05, batch_size=64,
                       seed=0).fit(splits.pool, splits.val)
    info = model.blend_info
    names = splits.pool.joint_names
    # the case is one where the plain sum IS worse than the physics on some joint ...
    assert any(info["val_mse_sum"][n] > 1.2 * info["val_mse_physics"][n] for n in names), info
    val, test = splits.val, splits.test
    for j, n in enumerate(names):
        w = model.network_weight[n]
        assert 0.0 <= w <= 1.0
        rows = val.moving[:, j]
        hybrid_val = float(((val.tau - model.predict_dataset(val))[rows, j] ** 2).mean())
        physics_val = float(((val.tau - model.rigid.predict_dataset(val))[rows, j] ** 2).mean())
        # ... and the hybrid is not (the weight is chosen on exactly these samples; float32 network)
        assert hybrid_val <= physics_val * (1 + 1e-6) + 1e-12, (n, hybrid_val, physics_val, w)
        assert hybrid_val == pytest.approx(info["val_mse_hybrid"][n], rel=1e-4)
    # held out (the paper's test samples): no worse than the physics beyond noise
    after = mse(test.tau, model.predict_dataset(test))
    physics = mse(test.tau, model.rigid.predict_dataset(test))
    assert np.all(after <= 1.05 * physics), (after, physics)
    # the weight is part of the saved network: loading gives the same prediction and weights
    np.testing.assert_allclose(model.predict_dataset(test),
                               model.rigid.predict_dataset(test) + model.mlp.predict_dataset(test))


def test_the_hybrid_weight_survives_save_and_load(tmp_path, hybrid, splits):
    hybrid.save(tmp_path / "m")
    loaded = load_model(tmp_path / "m")
    assert loaded.network_weight == pytest.approx(hybrid.network_weight)
    assert set(loaded.blend_info["val_mse_hybrid"]) == set(splits.pool.joint_names)
    # the session's friction is missing from the physics part: the network is kept (weight near 1)
    assert all(w > 0.5 for w in hybrid.network_weight.values()), hybrid.network_weight
