"""The crane-train sample-size sweep: batched MLP training against a plain one-model-at-a-time loop.

Data: a 10-minute synthetic session (tests/sessions.py: the CRANE-X7 rigid-body dynamics of joints 1, 2,
4 with Coulomb and viscous friction and stick phases), preprocessed the paper's way, split into the
paper's pool 6000 / validation 500 / test 500.
Full run: 10 sizes (300..3000), 10 trials, 3 methods, 100 epochs = 200 MLPs + 100 rigid-body fits,
timed twice in the same process on the same splits and draws:
  * batched: train.evaluation.sweep.run_sweep (all 200 MLPs in one train.models.batched run);
  * plain:   the same MLPs one after another with train.models.batched.train_plain (nn.Sequential,
             torch.optim.Adam, a Python loop over minibatches), the rigid-body fits as in the sweep.
Quick run: 3 sizes (300, 1500, 3000), 3 trials, 100 epochs; nothing is extrapolated.
torch uses 1 intra-op thread (fastest for 9-64-3 networks; measured, see docs/train.md).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]


def _dataset(minutes: float = 10.0):
    sys.path.insert(0, str(ROOT))
    from tests.sessions import write_synthetic_session
    from train.data.preprocess import preprocess
    from train.data.session import read_sessions

    with tempfile.TemporaryDirectory() as tmp:
        path, _ = write_synthetic_session(Path(tmp) / "bench.h5", minutes * 60, seed=0)
        return preprocess(read_sessions([path]))


def plain_sweep(ds, sizes, trials, seed, settings):
    """The sweep's MLPs trained one at a time; returns {method: (S, T, J) test MSE} and seconds."""
    from train.data.splits import make_splits
    from train.evaluation.metrics import mse
    from train.evaluation.sweep import draw_subsets, mlp_jobs, run_rigid_body
    from train.models.batched import predict, train_plain
    from train.models.mlp import features

    splits = make_splits(ds, seed=seed)
    subsets = draw_subsets(len(splits.pool), sizes, trials, seed)
    start = time.perf_counter()
    run_rigid_body(splits, subsets, sizes, trials, progress=False)
    job = mlp_jobs(splits, subsets, sizes, trials, ["mlp-mse", "mlp-masked"], seed)
    Xv = features(splits.val.q, splits.val.dq, splits.val.ddq)
    Xt = features(splits.test.q, splits.test.dq, splits.test.ddq)
    out = {m: np.full((len(sizes), trials, 3), np.nan) for m in ("mlp-mse", "mlp-masked")}
    for (method, s, trial), rows, sd in zip(job["keys"], job["rows"], job["seeds"]):
        res = train_plain(job["X"], job["Y"], job["W"], rows, Xv, splits.val.tau, settings, seed=sd)
        out[method][s, trial] = mse(splits.test.tau, predict(res.params, res.norm, Xt)[0])
    return out, time.perf_counter() - start


def run(quick: bool) -> list[dict]:
    from train.evaluation.sweep import run_sweep
    from train.models.batched import MLPSettings

    torch.set_num_threads(1)
    sizes = [300, 1500, 3000] if quick else list(range(300, 3001, 300))
    trials = 3 if quick else 10
    settings = MLPSettings(epochs=100)
    ds = _dataset()
    start = time.perf_counter()
    result = run_sweep(ds, sizes, trials, seed=0, progress=False, mlp_settings=settings, threads=1)
    t_batched = time.perf_counter() - start
    plain, t_plain = plain_sweep(ds, sizes, trials, 0, settings)
    n_mlp = 2 * len(sizes) * trials
    label = f"{len(sizes)} sizes x {trials} trials x 3 methods, 100 epochs ({n_mlp} MLPs)"
    rows = [
        {"benchmark": "sweep", "metric": "batched sweep", "value": t_batched, "unit": "s", "note": label},
        {"benchmark": "sweep", "metric": "plain loop sweep", "value": t_plain, "unit": "s", "note": label},
        {"benchmark": "sweep", "metric": "speed-up", "value": t_plain / t_batched, "unit": "x",
         "note": "goal >= 5x"},
        {"benchmark": "sweep", "metric": "batched MLP part", "value": result.meta["timing"]["mlp_s"],
         "unit": "s", "note": f"rigid-body part {result.meta['timing']['rigid-body_s']:.1f} s"},
    ]
    for method in ("mlp-mse", "mlp-masked"):
        b = np.array(result.methods[method]["mse_mean"], dtype=float)[-1].mean()
        p = np.nanmean(plain[method][-1])
        rows.append({"benchmark": "sweep", "metric": f"{method} test MSE at {sizes[-1]}, batched/plain",
                     "value": b / p, "unit": "ratio", "note": f"batched {b:.3g}, plain {p:.3g} (N m)^2"})
    return rows


if __name__ == "__main__":
    for row in run("--quick" in sys.argv):
        print(row)
