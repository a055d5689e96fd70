"""The paper's experiment: test error against the number of training samples, per method.

For every size and trial a random subset of `size` samples is drawn from the training pool (the same
subset for every method); each method trains on its own usable part of it (rigid-body and mlp-mse: the
samples in which every joint moves; mlp-masked: all of them, with the dead-zone mask in its loss) and is
scored on the test set (500 samples, every joint moving; from 4 joints on per joint: each joint over the
500+ test rows where it moves, train.data.splits "eval_set") with the weights of its best validation epoch.
All MLPs of the sweep (methods x sizes x trials) train together in one batched run (train.models.batched);
the rigid-body fits are cheap and run one after the other.

Reported per method, size and joint: test MSE mean over the trials and the half-width of its 95 %
confidence interval (Student t, trials - 1 degrees of freedom), RMSE (N m, mean over trials of the
per-trial RMSE) and normalised MSE (MSE / variance of the test torque).
"""

from __future__ import annotations

import csv
import io
import json
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy import stats
from tqdm import tqdm

from crane_io.errors import CraneError

from ..data.dataset import Dataset
from ..data.masks import moving_fractions
from ..data.splits import SplitConfig, Splits, eval_mask, make_splits
from ..models.batched import MLPSettings, predict, train_mlps
from ..models.method_names import SWEEP_METHODS
from ..models.mlp import features
from ..models.rigid_body import RigidBodyModel
from ..progress import ProgressLines
from .metrics import mse, torque_variance

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

RESULTS_VERSION = 1
TABLE_JOINTS = 4  # joint columns per printed table (7 joints: a table of 4, then one of 3)


class SweepError(CraneError):
    """A sweep that cannot run as asked."""


@dataclass
class SweepResult:
    joints: list
    sizes: list
    trials: int
    methods: dict  # name -> {sizes, mse_mean, mse_ci95, mse_trials, rmse_mean, nmse_mean, train_rows_mean}
    usable_fraction: dict  # of the training pool: {per_joint: {name: f}, all_joints: f}
    window: dict  # t, tau, moving, predictions {method: (n, J)} of models trained on the largest size
    meta: dict = field(default_factory=dict)
    sizes_requested: list | None = None  # as asked; `sizes` differ from them when sizes_scaled
    sizes_scaled: bool = False  # --scale-to-data shrank (or dropped) sizes to fit the training pool

    def to_json(self) -> dict:
        return {"format": "crane-sweep-results", "format_version": RESULTS_VERSION, "joints": self.joints,
                "sizes": self.sizes, "sizes_requested": self.sizes_requested or self.sizes,
                "sizes_scaled": self.sizes_scaled, "trials": self.trials,
                "usable_fraction": self.usable_fraction, "methods": self.methods, "window": self.window,
                "meta": self.meta}


def _span(sizes) -> str:
    return f"{sizes[0]}..{sizes[-1]}" if len(sizes) > 1 else f"{sizes[0]}"


def scaled_sizes_sentence(doc: dict) -> str | None:
    """One sentence saying that (and how) the sizes were scaled to the data; None when they were not.
    `doc`: a results.json document (SweepResult.to_json())."""
    if not doc.get("sizes_scaled"):
        return None
    meta = doc.get("meta") or {}
    pool = meta.get("splits", {}).get("pool")
    used, asked = _span(doc["sizes"]), _span(doc["sizes_requested"])
    if meta.get("split_scale", 0) >= 1:  # the splits fitted unscaled: only sizes above the pool went
        return f"the sizes above the training pool of {pool} samples were left out: {used} instead of {asked}"
    held = f" (the training pool holds {pool} samples)" if pool else ""
    return f"the sizes were scaled to the data: {used} samples instead of {asked}{held}"


def _ci95(values: np.ndarray) -> np.ndarray:
    """Half-width of the 95 % t confidence interval of the mean along axis 0 (NaN-aware)."""
    n = np.sum(np.isfinite(values), axis=0)
    with warnings.catch_warnings():  # a joint with fewer than 2 scored trials: NaN, said by n below
        warnings.simplefilter("ignore", RuntimeWarning)
        sd = np.nanstd(values, axis=0, ddof=1) if values.shape[0] > 1 else np.full(values.shape[1:], np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = stats.t.ppf(0.975, np.maximum(n - 1, 1))
        return np.where(n > 1, t * sd / np.sqrt(np.maximum(n, 1)), np.nan)


def draw_subsets(pool_size: int, sizes: Sequence[int], trials: int, seed: int) -> dict:
    """{(size, trial): sorted row indices into the pool}; the same draws for every method."""
    out = {}
    for size in sizes:
        for trial in range(trials):
            rng = np.random.default_rng([seed, size, trial])
            out[(size, trial)] = np.sort(rng.choice(pool_size, size, replace=False))
    return out


def _summarise(per_trial: np.ndarray, test_var: np.ndarray, sizes, rows_used) -> dict:
    """per_trial (S, T, J) test MSE -> the JSON block of one method."""
    with np.errstate(invalid="ignore"):
        mean = np.nanmean(per_trial, axis=1)
        rmse = np.nanmean(np.sqrt(per_trial), axis=1)
    ci = np.stack([_ci95(per_trial[s]) for s in range(len(sizes))])
    clean = lambda a: [[None if not np.isfinite(v) else float(v) for v in row] for row in a]  # noqa: E731
    return {"sizes": list(sizes), "mse_mean": clean(mean), "mse_ci95": clean(ci),
            "mse_trials": [clean(per_trial[s]) for s in range(len(sizes))], "rmse_mean": clean(rmse),
            "nmse_mean": clean(mean / test_var[None, :]),
            "train_rows_mean": [float(np.mean(r)) for r in rows_used]}


def run_rigid_body(splits: Splits, subsets: dict, sizes: Sequence[int], trials: int, progress: bool = True,
                   effects: Sequence = (), lines: ProgressLines | None = None
                   ) -> tuple[np.ndarray, list[list[int]], RigidBodyModel | None]:
    """(S, T, J) test MSE, rows used per (size, trial), and the model of trial 0 at the largest size.
    `lines`: plain progress lines (for a log), at most one per size, the last one always."""
    J = len(splits.pool.joint_names)
    out = np.full((len(sizes), trials, J), np.nan)
    rows_used = [[0] * trials for _ in sizes]
    largest = None
    bar = tqdm(total=len(sizes) * trials, desc="rigid-body", disable=not progress, leave=False)
    for s, size in enumerate(sizes):
        for trial in range(trials):
            train = splits.pool.subset(subsets[(size, trial)])
            rows_used[s][trial] = int(train.all_moving.sum())
            try:
                model = RigidBodyModel(train.joint_names, effects=effects).fit(train, splits.val)
            except CraneError:
                bar.update()
                continue  # too few all-moving samples at this size: no score (NaN)
            out[s, trial] = mse(splits.test.tau, model.predict_dataset(splits.test), eval_mask(splits.test))
            if s == len(sizes) - 1 and trial == 0:
                largest = model
            bar.update()
        if lines is not None:
            last = s == len(sizes) - 1
            lines(f"rigid-body, size {s + 1}/{len(sizes)} ({size} samples), {(s + 1) * trials} of "
                  f"{len(sizes) * trials} fits done", force=last)
    bar.close()
    return out, rows_used, largest


def mlp_jobs(splits: Splits, subsets: dict, sizes: Sequence[int], trials: int, methods: Sequence[str],
             seed: int) -> dict:
    """Everything the MLPs of a sweep train on: stacked data X, Y, W (rows < N: the pool with the
    dead-zone mask as loss weights, for the masked loss; rows >= N: the same pool with weight 1, for MSE),
    and per model its key (method, size index, trial), training rows and seed."""
    pool = splits.pool
    X = features(pool.q, pool.dq, pool.ddq)
    N = len(X)
    job = {"X": np.vstack([X, X]), "Y": np.vstack([pool.tau, pool.tau]),
           "W": np.vstack([pool.moving.astype(np.float32), np.ones_like(pool.tau, dtype=np.float32)]),
           "keys": [], "rows": [], "seeds": []}
    all_moving = pool.all_moving
    for mi, method in enumerate(methods):
        for s, size in enumerate(sizes):
            for trial in range(trials):
                sub = subsets[(size, trial)]
                r = sub if method == "mlp-masked" else sub[all_moving[sub]] + N
                if len(r) < 2:
                    continue
                job["keys"].append((method, s, trial))
                job["rows"].append(r)
                job["seeds"].append(int(np.random.SeedSequence([seed, mi, size, trial]).generate_state(1)[0]))
    return job


def run_mlps(splits: Splits, subsets: dict, sizes: Sequence[int], trials: int, methods: Sequence[str],
             settings: MLPSettings, seed: int, progress: bool = True, lines: ProgressLines | None = None
             ) -> tuple[dict[str, tuple[np.ndarray, list[list[int]]]], dict[str, np.ndarray]]:
    """Every MLP of the sweep in one batched run. Returns {method: ((S, T, J) mse, rows_used)} and the
    window predictions of trial 0 at the largest size. `lines`: plain progress lines (for a log) per
    epoch when due, the last epoch always."""
    job = mlp_jobs(splits, subsets, sizes, trials, methods, seed)
    keys, rows = job["keys"], job["rows"]
    J = splits.pool.tau.shape[1]
    results = {m: (np.full((len(sizes), trials, J), np.nan), [[0] * trials for _ in sizes]) for m in methods}
    window_pred = {}
    if not keys:
        return results, window_pred
    val = splits.val
    bar = tqdm(total=settings.epochs, desc=f"{len(keys)} MLPs", unit="epoch", disable=not progress,
               leave=False)

    def step(done, total):
        bar.update(1)
        if lines is not None:
            lines(f"{len(keys)} networks ({', '.join(methods)}), epoch {done}/{total}"
                  + (" (trained)" if done >= total else ""), force=done >= total)

    res = train_mlps(job["X"], job["Y"], job["W"], rows, features(val.q, val.dq, val.ddq), val.tau, settings,
                     seeds=job["seeds"], progress=step, W_val=eval_mask(val))
    bar.close()
    test, win = splits.test, splits.window
    pred = predict(res.params, res.norm, features(test.q, test.dq, test.ddq))  # (M, n, J)
    wpred = predict(res.params, res.norm, features(win.q, win.dq, win.ddq))
    for m, (method, s, trial) in enumerate(keys):
        results[method][0][s, trial] = mse(test.tau, pred[m], eval_mask(test))
        results[method][1][s][trial] = len(rows[m])
        if s == len(sizes) - 1 and trial == 0:
            window_pred[method] = wpred[m]
    return results, window_pred


def _checked_request(methods: Sequence[str], trials: int,
                     sizes: Sequence[int]) -> tuple[list[str], list[int]]:
    """The methods (each once, in order) and sorted distinct sizes asked for, checked."""
    methods = list(dict.fromkeys(methods))
    unknown = [m for m in methods if m not in SWEEP_METHODS]
    if unknown:
        raise SweepError(f"the sweep runs {', '.join(SWEEP_METHODS)}; "
                         f"{', '.join(unknown)} is not one of them")
    if not methods:
        raise SweepError("no method to sweep")
    if trials < 1:
        raise SweepError(f"the number of trials must be at least 1, got {trials}")
    sizes = sorted({int(s) for s in sizes})
    if not sizes or sizes[0] < 1:
        raise SweepError("sample sizes must be positive integers")
    return methods, sizes


def _sizes_in_pool(sizes: list[int], pool_n: int, scale: float, scale_to_data: bool) -> list[int]:
    """The sizes, scaled to the data (with `scale_to_data`) when the largest exceeds the training pool."""
    if sizes[-1] <= pool_n:
        return sizes
    if not scale_to_data:
        raise SweepError(f"the largest sample size {sizes[-1]} exceeds the training pool of "
                         f"{pool_n} samples")
    scaled = (max(1, int(round(s * scale))) for s in sizes)
    sizes = sorted({s for s in scaled if s <= pool_n})
    if not sizes:
        raise SweepError(f"no sample size fits the training pool of {pool_n} samples, even scaled "
                         f"to the data (x{scale:.3g}); ask for smaller sizes")
    return sizes


def _plan_line(methods: list[str], sizes: list[int], trials: int, settings: MLPSettings) -> str:
    """One line saying what the sweep is about to fit and train."""
    mlp_n = sum(m.startswith("mlp-") for m in methods) * len(sizes) * trials
    plan = [f"{len(sizes) * trials} rigid-body fits"] if "rigid-body" in methods else []
    plan += [f"{mlp_n} networks trained together for {settings.epochs} epochs"] if mlp_n else []
    plural = lambda n, word: f"{n} {word}" + ("s" if n != 1 else "")  # noqa: E731
    return (f"{plural(len(methods), 'method')} x {plural(len(sizes), 'size')} ({_span(sizes)} samples) x "
            f"{plural(trials, 'trial')}: " + ", then ".join(plan))


def _run_methods(splits, subsets, sizes, trials, methods, settings, seed, bars, lines, test_var):
    """Each method's summary, its predictions on the window and the seconds each family took."""
    out_methods, predictions, timing = {}, {}, {}
    if "rigid-body" in methods:
        t = time.perf_counter()
        per_trial, rows_used, model = run_rigid_body(splits, subsets, sizes, trials, bars, lines=lines)
        out_methods["rigid-body"] = _summarise(per_trial, test_var, sizes, rows_used)
        if model is not None:
            predictions["rigid-body"] = model.predict_dataset(splits.window)
        timing["rigid-body_s"] = time.perf_counter() - t
    mlp_methods = [m for m in methods if m.startswith("mlp-")]
    if mlp_methods:
        t = time.perf_counter()
        res, wpred = run_mlps(splits, subsets, sizes, trials, mlp_methods, settings, seed, bars, lines)
        for m in mlp_methods:
            out_methods[m] = _summarise(res[m][0], test_var, sizes, res[m][1])
        predictions.update(wpred)
        timing["mlp_s"] = time.perf_counter() - t
    return out_methods, predictions, timing


def run_sweep(dataset: Dataset, sizes: Sequence[int], trials: int = 10,
              methods: Sequence[str] = SWEEP_METHODS, seed: int = 0,
              progress: bool | ProgressLines = True, split_config: SplitConfig | None = None,
              scale_to_data: bool = False, mlp_settings: MLPSettings | None = None, threads: int | None = 1,
              notify: Callable[[str | None], object] | None = None) -> SweepResult:
    """Run the experiment; see the module docstring. `threads` sets torch's intra-op threads
    (1 is fastest for these tiny networks; None leaves torch's setting alone). `progress`: True for
    tqdm bars, False for nothing, a train.progress.ProgressLines for plain lines (a log). `notify`:
    callable(str) told, before any training, when scale_to_data changed the sizes (one sentence)."""
    lines = progress if isinstance(progress, ProgressLines) else None
    bars = bool(progress) and lines is None
    methods, sizes = _checked_request(methods, trials, sizes)
    requested = list(sizes)
    settings = mlp_settings or MLPSettings()
    if threads is not None:
        torch.set_num_threads(threads)
    t0 = time.perf_counter()
    splits = make_splits(dataset, split_config, seed=seed, scale_to_data=scale_to_data)
    pool_n = len(splits.pool)
    sizes = _sizes_in_pool(sizes, pool_n, splits.scale, scale_to_data)
    sizes_scaled = sizes != requested
    if sizes_scaled and notify is not None:
        notify(scaled_sizes_sentence({"sizes": sizes, "sizes_requested": requested, "sizes_scaled": True,
                                      "meta": {"splits": {"pool": pool_n}, "split_scale": splits.scale}}))
    subsets = draw_subsets(pool_n, sizes, trials, seed)
    if lines is not None:
        lines(_plan_line(methods, sizes, trials, settings), force=True)
    test_var = torque_variance(splits.test.tau, eval_mask(splits.test))
    out_methods, predictions, timing = _run_methods(splits, subsets, sizes, trials, methods, settings, seed,
                                                    bars, lines, test_var)
    timing["total_s"] = time.perf_counter() - t0
    out_methods = {m: out_methods[m] for m in methods if m in out_methods}
    win = splits.window
    window = {"t": win.t.tolist(), "tau": win.tau.tolist(), "moving": win.moving.tolist(),
              "size": sizes[-1], "predictions": {m: np.asarray(p).tolist() for m, p in predictions.items()}}
    meta = {"seed": seed, "splits": {k: len(v) for k, v in splits.index.items()}, "split_scale": splits.scale,
            "mlp": {"hidden": settings.hidden, "lr": settings.lr, "epochs": settings.epochs,
                    "batch_size": settings.batch_size},
            "test_torque_variance": test_var.tolist(),
            "usable_fraction_all_data": moving_fractions(dataset.moving, dataset.joint_names),
            "preprocessing": dataset.meta.get("preprocessing"), "sigma": dataset.meta.get("sigma"),
            "sources": dataset.meta.get("sources"), "timing": timing,
            "eval_set": splits.test.meta.get("eval_set", "all-moving")}
    return SweepResult(list(dataset.joint_names), sizes, trials, out_methods,
                       moving_fractions(splits.pool.moving, dataset.joint_names), window, meta,
                       sizes_requested=requested, sizes_scaled=sizes_scaled)


def format_table(result: SweepResult | dict) -> str:
    """Plain-text table: test MSE mean +- 95 % CI per method, size and joint, plus usable fractions."""
    doc = result.to_json() if isinstance(result, SweepResult) else result
    joints = doc["joints"]
    uf = doc["usable_fraction"]
    lines = ["usable fraction of the training pool: "
             + ", ".join(f"{j} {uf['per_joint'][j]:.0%}" for j in joints)
             + f", all joints {uf['all_joints']:.0%}"]
    scaled = scaled_sizes_sentence(doc)
    if scaled:
        lines.append(scaled[0].upper() + scaled[1:] + ".")
    per_joint = doc.get("meta", {}).get("eval_set") == "per-joint"
    lines += ["", "test MSE [(N m)^2], mean +- 95% CI over {} trials".format(doc["trials"])
              + (", each joint on the test rows where it moves" if per_joint else "")]

    def cell(m, c):
        if m is None:
            return f"{'-':>24}"
        return f"{m:>12.3g} +- {c:<8.2g}" if c is not None else f"{m:>12.3g}{'':12}"

    # at most TABLE_JOINTS joint columns side by side (a terminal's width); more joints: further tables
    for start in range(0, len(joints), TABLE_JOINTS):
        cols = range(start, min(start + TABLE_JOINTS, len(joints)))
        head = f"{'method':<12}{'size':>6}" + "".join(f"{joints[j]:>24}" for j in cols)
        lines += ([""] if start else []) + [head, "-" * len(head)]
        for method, r in doc["methods"].items():
            for s, size in enumerate(r["sizes"]):
                row = "".join(cell(r["mse_mean"][s][j], r["mse_ci95"][s][j]) for j in cols)
                lines.append(f"{method:<12}{size:>6}{row}")
    return "\n".join(lines)


# the files `write_results` writes in the output folder
RESULT_FILES = {"json": "results.json", "csv": "results.csv", "mse_plot": "mse_vs_samples.png",
                "window_plot": "window_torque.png"}


def result_paths(out_dir: Path | str) -> dict:
    """The paths of the files `write_results` writes in `out_dir` (RESULT_FILES)."""
    return {key: Path(out_dir) / name for key, name in RESULT_FILES.items()}


def write_results(result: SweepResult, out_dir: Path | str) -> dict:
    """results.json, results.csv, mse_vs_samples.png and window_torque.png in out_dir (made if missing),
    each written atomically (crane_io.output_files); returns the paths."""
    from crane_io.output_files import write_text_atomic

    from .plots import plot_mse_vs_samples, plot_window

    doc = result.to_json()
    paths = result_paths(out_dir)
    write_text_atomic(paths["json"], json.dumps(doc, indent=1), "sweep results")
    rows = io.StringIO(newline="")
    w = csv.writer(rows)
    w.writerow(["method", "size", "joint", "mse_mean", "mse_ci95", "rmse_mean_nm", "nmse_mean",
                "train_rows_mean", "trials"])
    for method, r in doc["methods"].items():
        for s, size in enumerate(r["sizes"]):
            for j, joint in enumerate(doc["joints"]):
                w.writerow([method, size, joint, r["mse_mean"][s][j], r["mse_ci95"][s][j],
                            r["rmse_mean"][s][j], r["nmse_mean"][s][j], r["train_rows_mean"][s],
                            doc["trials"]])
    write_text_atomic(paths["csv"], rows.getvalue(), "sweep results")
    plot_mse_vs_samples(doc, paths["mse_plot"])
    largest = f"{result.window['size']} samples"
    if doc["sizes_scaled"]:
        largest += f" (the largest size, {doc['sizes_requested'][-1]} scaled to the data)"
    plot_window(result.window, doc["joints"], paths["window_plot"],
                f"measured and predicted torque, models trained on {largest}; grey: dead zone")
    return paths
