"""The paper's two figures, drawn with matplotlib (Agg backend, PNG files).

* `plot_mse_vs_samples`: test MSE against number of training samples, mean and 95 % confidence band
  over the trials, one panel per joint, one line per method (the paper's Fig. 5).
* `plot_window`: measured and predicted torque over the continuous plot window, the periods in which
  a joint is in its dead zone shaded grey (the paper's Fig. 6).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

COLORS = {"rigid-body": "tab:green", "mlp-mse": "tab:blue", "mlp-masked": "tab:red", "hybrid": "tab:purple"}
LABELS = {"rigid-body": "Newton-Euler (RLS)", "mlp-mse": "FF-NN, MSE", "mlp-masked": "FF-NN, masked loss",
          "hybrid": "hybrid"}


def plot_mse_vs_samples(results: dict, path) -> Path:
    """`results` is the results.json document (train.sweep.SweepResult.to_json())."""
    joints = results["joints"]
    fig, axes = plt.subplots(1, len(joints), figsize=(4.2 * len(joints), 3.6), squeeze=False)
    for j, (ax, name) in enumerate(zip(axes[0], joints)):
        for method, r in results["methods"].items():
            sizes = np.asarray(r["sizes"], dtype=float)
            mean = np.array([row[j] for row in r["mse_mean"]], dtype=float)
            ci = np.array([row[j] for row in r["mse_ci95"]], dtype=float)
            color = COLORS.get(method)
            ax.plot(sizes, mean, "o-", ms=3, color=color, label=LABELS.get(method, method))
            ax.fill_between(sizes, mean - ci, mean + ci, color=color, alpha=0.2, lw=0)
        ax.set_title(name)
        ax.set_xlabel("number of training samples")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("test MSE [(N m)$^2$]")
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"mean and 95 % CI over {results.get('trials', '?')} trials")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def _shade(ax, t, still):
    """Grey spans where `still` (bool per sample) is True."""
    if not still.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]])))
    dt = np.median(np.diff(t)) if len(t) > 1 else 0.0
    for a, b in zip(edges[::2], edges[1::2]):
        ax.axvspan(t[a] - dt / 2, t[b - 1] + dt / 2, color="0.85", lw=0, zorder=0)


def plot_window(window: dict, joints, path, title: str = "") -> Path:
    """window: {'t': (n,), 'tau': (n, J), 'moving': (n, J), 'predictions': {method: (n, J)}}."""
    t = np.asarray(window["t"], dtype=float)
    t = t - t[0]
    tau = np.asarray(window["tau"], dtype=float)
    moving = np.asarray(window["moving"], dtype=bool)
    fig, axes = plt.subplots(1, len(joints), figsize=(4.2 * len(joints), 3.4), squeeze=False)
    for j, (ax, name) in enumerate(zip(axes[0], joints)):
        _shade(ax, t, ~moving[:, j])
        ax.plot(t, tau[:, j], color="k", lw=1.6, label="measured")
        for method, pred in window["predictions"].items():
            ax.plot(t, np.asarray(pred, dtype=float)[:, j], color=COLORS.get(method), lw=1.1,
                    label=LABELS.get(method, method))
        ax.set_title(name)
        ax.set_xlabel("time [s]")
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("torque [N m]")
    axes[0][0].legend(fontsize=8)
    fig.suptitle(title or "measured and predicted torque (grey: dead zone)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)
