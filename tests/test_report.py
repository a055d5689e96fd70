"""The HTML report: self-contained, every section present, evaluated only on held-out rows."""

from __future__ import annotations

import re

import numpy as np
import pytest

from train.data.dataset import Dataset
from train.data.splits import SplitConfig, make_splits
from train.evaluation.heldout import held_out, held_out_rows
from train.evaluation.report import binned_means, error_stats, region_table, report_html

JOINTS = ("joint1", "joint2", "joint4")


def toy_dataset(n=9000, seed=0) -> Dataset:
    """A smooth 3-joint motion with stick phases and a torque the toy model half explains."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 50.0
    q = np.stack([0.8 * np.sin(0.31 * t * (j + 1) + j) + 0.2 * np.sin(1.3 * t + 2 * j) for j in range(3)], 1)
    dq = np.gradient(q, t, axis=0)
    ddq = np.gradient(dq, t, axis=0)
    stick = (np.sin(0.05 * t[:, None] * np.array([1.0, 1.7, 2.3]) + np.array([0, 1, 2])) > 0.6)
    moving = ~stick & (np.abs(dq) > 0.02)
    tau = 0.5 * np.sin(q) + 0.2 * np.sign(dq) + rng.normal(0, 0.02, (n, 3))
    return Dataset(JOINTS, t, q, dq, ddq, tau, moving, 50.0)


class SineModel:
    """Knows the gravity-like term but not the friction."""

    method = "toy"
    options = {"effects": [["offset", "joint1", None]]}

    def predict(self, q, dq, ddq):
        return 0.5 * np.sin(q)


@pytest.fixture(scope="module")
def held():
    ds = toy_dataset()
    splits = make_splits(ds, SplitConfig(n_pool=2000, n_val=300, n_test=300), seed=3)
    return ds, splits, held_out(ds, splits, ["toy.h5"], seed=3)


def test_held_out_rows_never_touch_training_or_validation(held):
    ds, splits, h = held
    rows = held_out_rows(ds, splits)
    assert not set(rows) & set(splits.index["pool"].tolist())
    assert not set(rows) & set(splits.index["val"].tolist())
    assert set(splits.index["test"].tolist()) <= set(rows)
    assert set(splits.index["window"].tolist()) <= set(rows)
    assert h.test.sum() == len(splits.index["test"])
    # the test blocks' dead-zone rows are kept too, so the report can show the error there
    assert (~h.data.all_moving).any()


def test_report_is_self_contained_with_every_section(held):
    _, _, h = held
    page = report_html(SineModel(), "models/toy", h, ["toy.h5"])
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    # opens offline: nothing is fetched from anywhere
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", page)
    assert "http://" not in page and "https://" not in page
    images = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", page)
    assert len(images) == 2 * len(JOINTS)
    assert all(len(b) > 1000 for b in images)
    for section in ("Summary", "Evaluated on held-out data", "Torque and residual over time",
                    "Residual against angle, velocity and acceleration", "Error by region",
                    "dead zone", "normalised MSE", "offset:joint=joint1"):
        assert section in page, section
    for joint in JOINTS:
        assert f"id='joint-{joint}'" in page


def test_summary_numbers_match_the_held_out_error(held):
    _, _, h = held
    page = report_html(SineModel(), "m", h)
    ds = h.data
    err = ds.tau[h.test, 1] - 0.5 * np.sin(ds.q[h.test, 1])
    assert f"{np.mean(err ** 2):.4g}" in page


def test_region_table_splits_error_by_motion_speed_and_angle(held):
    _, _, h = held
    ds = h.data
    pred = SineModel().predict(ds.q, ds.dq, ds.ddq)
    rows = region_table(h, pred, 0)
    groups = {r["group"] for r in rows}
    assert groups == {"motion", "speed (moving samples)", "angle (all samples)"}
    motion = [r for r in rows if r["group"] == "motion"]
    assert sum(r["n"] for r in motion) == len(ds)
    assert sum(r["share"] for r in motion) == pytest.approx(1.0)
    angle = [r for r in rows if r["group"].startswith("angle")]
    assert sum(r["n"] for r in angle) == len(ds)


def test_binned_means_recover_a_known_curve_with_intervals():
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, 4000)
    y = 2 * x + rng.normal(0, 0.1, x.size)
    c, m, h, n = binned_means(x, y, bins=10)
    assert len(c) == 10 and n.sum() == x.size
    assert np.all(np.abs(m - 2 * c) < 4 * h + 0.02)
    assert np.all(h > 0) and np.all(h < 0.05)


def test_error_stats_normalised_mse():
    tau = np.array([1.0, -1.0, 1.0, -1.0])
    s = error_stats(tau, np.zeros(4))
    assert s["mse"] == pytest.approx(1.0) and s["nmse"] == pytest.approx(1.0)
    assert s["rmse"] == pytest.approx(1.0)
    assert error_stats(tau, tau)["nmse"] == 0.0
