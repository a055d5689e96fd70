"""One arm's torque prediction for one sample, as the bilateral loop needs it every 2 ms cycle: the float64
numpy path (train.models.fast_predict.NumpyPredictor) against the model's own `predict` (torch for the
networks, the vectorised regressor and effect columns for the physics), in the same process; and what the
control loop really runs, `crane_io.physics.loop_model.LoopModel.load(dir).predict_one` (the saved model's
loop_model.npz, no torch), for mlp-masked, rigid-body and hybrid, against the goal of 20 us per call.

Models: each method fitted on 400 synthetic samples of joints 1, 2, 4 (the CRANE-X7 rigid-body dynamics
plus Coulomb and viscous friction), saved and loaded back (the network 9-64-3, the paper's size; a few
epochs: the weights' values do not change the time). rigid-body and hybrid carry effects (Coulomb and
viscous on every joint, a Stribeck term on joint 2), as a modelling loop's model would.
Each call is timed alone (perf_counter_ns around it) over many calls on varied inputs; median and p99.
torch uses 1 intra-op thread. The load average at the start is in the notes: the machine may be shared.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

JOINTS = ("joint1", "joint2", "joint4")
LOOP_METHODS = ("mlp-masked", "rigid-body", "hybrid")  # timed as the control loop loads them
GOAL_US = 20.0  # per call: a small part of the 2 ms cycle
EFFECTS = [["coulomb", None, None], ["viscous", None, None],
           ["stribeck", "joint2", {"stribeck_velocity": 0.05}]]


def _data(n: int, seed: int):
    from crane_io.physics.dynamics import ArmDynamics
    from train.data.dataset import Dataset

    rng = np.random.default_rng(seed)
    q, dq, ddq = rng.uniform(-1, 1, (n, 3)), rng.uniform(-2, 2, (n, 3)), rng.uniform(-10, 10, (n, 3))
    tau = ArmDynamics(joints=JOINTS).inverse_dynamics(q, dq, ddq) + 0.2 * np.sign(dq) + 0.05 * dq
    return Dataset(JOINTS, np.arange(n) * 0.02, q, dq, ddq, tau, rng.random((n, 3)) < 0.8, 50.0)


def _models(folder: Path) -> dict:
    from train.data.preprocess import PreprocessConfig
    from train.models.registry import load_model, make_model

    ds = _data(400, 0)
    net = {"epochs": 3, "hidden": 64}
    options = {"mlp-mse": net, "mlp-masked": net, "rigid-body": {"effects": EFFECTS},
               "hybrid": {**net, "effects": EFFECTS}}
    pre = PreprocessConfig(joints=JOINTS).to_dict()  # the loop model needs the filters' settings
    return {m: load_model(make_model(m, JOINTS, preprocessing=pre, **o).fit(ds, ds).save(folder / m))
            for m, o in options.items()}


def _times_us(call, inputs) -> np.ndarray:
    clock = time.perf_counter_ns
    out = np.empty(len(inputs))
    for i, (q, dq, ddq) in enumerate(inputs):
        t0 = clock()
        call(q, dq, ddq)
        out[i] = clock() - t0
    return out / 1e3


def run(quick: bool = False) -> list[dict]:
    import torch

    from crane_io.physics.loop_model import LoopModel
    from train.models.fast_predict import NumpyPredictor

    torch.set_num_threads(1)
    load = os.getloadavg()[0]
    calls = 2000 if quick else 20000
    test = _data(calls, 1)
    one = [(test.q[i], test.dq[i], test.ddq[i]) for i in range(calls)]
    batch = [(q[None], dq[None], ddq[None]) for q, dq, ddq in one]
    rows, loop_rows = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for method, model in _models(Path(tmp)).items():
            if method in LOOP_METHODS:
                loop = LoopModel.load(Path(tmp) / method)
                for _ in range(2):
                    _times_us(loop.predict_one, one[:200])
                t = _times_us(loop.predict_one, one)
                med, p99 = float(np.median(t)), float(np.percentile(t, 99))
                verdict = "met" if p99 <= GOAL_US else "NOT met"
                loop_rows.append({"benchmark": "predict", "metric": f"{method} LoopModel.predict_one, median",
                                  "value": med, "unit": "us",
                                  "note": f"goal <= {GOAL_US:g} us; {calls} calls; load {load:.1f}"})
                loop_rows.append({"benchmark": "predict", "metric": f"{method} LoopModel.predict_one, p99",
                                  "value": p99, "unit": "us",
                                  "note": f"goal <= {GOAL_US:g} us at p99: {verdict}"})
            fast = NumpyPredictor.from_model(model)
            for _ in range(2):  # warm up both (first calls allocate, import, fill caches)
                _times_us(fast.predict_one, one[:200])
                _times_us(model.predict, batch[:200])
            ours = _times_us(fast.predict_one, one)
            theirs = _times_us(model.predict, batch)
            ratio = np.median(theirs) / np.median(ours)
            rows.append({"benchmark": "predict", "metric": f"{method} numpy one sample, median",
                         "value": float(np.median(ours)), "unit": "us",
                         "note": f"p99 {np.percentile(ours, 99):.1f} us; {calls} calls; load {load:.1f}"})
            rows.append({"benchmark": "predict", "metric": f"{method} model.predict one sample, median",
                         "value": float(np.median(theirs)), "unit": "us",
                         "note": f"p99 {np.percentile(theirs, 99):.1f} us; numpy path {ratio:.1f}x faster"})
    return rows + loop_rows


if __name__ == "__main__":
    for r in run(quick="--quick" in sys.argv):
        print(f"{r['metric']:<45} {r['value']:9.2f} {r['unit']}  {r['note']}")
