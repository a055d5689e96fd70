"""The hybrid model: physics with chosen effects plus a masked network on its residual."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.sessions import write_synthetic_session
from train.metrics import mse
from train.models.registry import load_model, make_model
from train.preprocess import preprocess
from train.session import read_sessions
from train.splits import SplitConfig, make_splits

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
