"""The paper's two figures, drawn with matplotlib (Agg backend, PNG files).

* `plot_mse_vs_samples`: test MSE against number of training samples, mean and 95 % confidence band
  over the trials, one panel per joint, one line per method (the paper's Fig. 5).
* `plot_window`: measured and predicted torque over the continuous plot window, the periods in which
  a joint is in its dead zone shaded grey (the paper's Fig. 6).
* `plot_comparison`: `crane-train compare`'s chart, the held-out error per joint of successive models,
  one group of bars per joint, one bar per model, on a log axis, with the change against the first
  model on each bar.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

if TYPE_CHECKING:
    from collections.abc import Sequence

    from matplotlib.figure import Figure

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import ticker  # noqa: E402

if TYPE_CHECKING:
    from .compare import Comparison

COLORS = {"rigid-body": "tab:green", "mlp-mse": "tab:blue", "mlp-masked": "tab:red", "hybrid": "tab:purple"}
LABELS = {"rigid-body": "Newton-Euler (RLS)", "mlp-mse": "FF-NN, MSE", "mlp-masked": "FF-NN, masked loss",
          "hybrid": "hybrid"}


MAX_PANELS_PER_ROW = 4  # more joints than this wrap onto further rows (7 joints: 4 + 3)


# the image formats a plot may be written in, by the output's suffix (no suffix: PNG)
PLOT_FORMATS = ("png", "pdf", "svg")


def plot_format(path: Path | str) -> str:
    """The image format of the plot file `path` from its suffix; ConfigError for another suffix."""
    from crane_io.errors import ConfigError

    suffix = Path(path).suffix.lower().lstrip(".")
    if not suffix:
        return "png"
    if suffix not in PLOT_FORMATS:
        raise ConfigError(f"a plot is written as {', '.join('.' + f for f in PLOT_FORMATS)}, not "
                          f".{suffix}: name the file {Path(path).stem}.png")
    return suffix


def save_figure(fig, path: Path | str, **kwargs) -> Path:
    """Write `fig` to `path` atomically (crane_io.output_files) in the format its suffix names, and close
    it."""
    from crane_io.output_files import atomic_path

    try:
        with atomic_path(path, "plot") as tmp:
            fig.savefig(tmp, format=plot_format(path), **kwargs)
    finally:
        plt.close(fig)
    return Path(path)


def _panels(n: int, width: float, height: float):
    """(fig, axes list of n, first-column axes): one panel per joint, at most MAX_PANELS_PER_ROW a row
    (one row of n for the paper's three joints, as before); the unused panels of the last row hidden."""
    ncol = min(n, MAX_PANELS_PER_ROW)
    nrow = -(-n // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(width * ncol, height * nrow), squeeze=False)
    flat = [ax for row in axes for ax in row]
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n], [row[0] for row in axes]


def plot_mse_vs_samples(results: dict, path: Path | str) -> Path:
    """`results` is the results.json document (train.evaluation.sweep.SweepResult.to_json())."""
    joints = results["joints"]
    title = f"mean and 95 % CI over {results.get('trials', '?')} trials"
    xlabel = "number of training samples"
    if results.get("sizes_scaled"):  # --scale-to-data shrank the sizes: say so, with both ranges
        used, asked = results["sizes"], results["sizes_requested"]
        title += f"; sizes scaled to the data: {used[0]}..{used[-1]} instead of {asked[0]}..{asked[-1]}"
        xlabel += " (scaled to the data)"
    fig, axes, first = _panels(len(joints), 4.2, 3.6)
    for j, (ax, name) in enumerate(zip(axes, joints)):
        for method, r in results["methods"].items():
            sizes = np.asarray(r["sizes"], dtype=float)
            mean = np.array([row[j] for row in r["mse_mean"]], dtype=float)
            ci = np.array([row[j] for row in r["mse_ci95"]], dtype=float)
            color = COLORS.get(method)
            ax.plot(sizes, mean, "o-", ms=3, color=color, label=LABELS.get(method, method))
            ax.fill_between(sizes, mean - ci, mean + ci, color=color, alpha=0.2, lw=0)
        ax.set_title(name)
        ax.set_xlabel(xlabel)
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    for ax in first:
        ax.set_ylabel("test MSE [(N m)$^2$]")
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


def _shade(ax, t, still):
    """Grey spans where `still` (bool per sample) is True."""
    if not still.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]])))
    dt = np.median(np.diff(t)) if len(t) > 1 else 0.0
    for a, b in zip(edges[::2], edges[1::2]):
        ax.axvspan(t[a] - dt / 2, t[b - 1] + dt / 2, color="0.85", lw=0, zorder=0)


def plot_window(window: dict, joints: Sequence[str], path: Path | str, title: str = "") -> Path:
    """window: {'t': (n,) s, 'tau': (n, J) N m, 'moving': (n, J) bool,
    'predictions': {method: (n, J) N m}}."""
    t = np.asarray(window["t"], dtype=float)
    t = t - t[0]
    tau = np.asarray(window["tau"], dtype=float)
    moving = np.asarray(window["moving"], dtype=bool)
    fig, axes, first = _panels(len(joints), 4.2, 3.4)
    for j, (ax, name) in enumerate(zip(axes, joints)):
        _shade(ax, t, ~moving[:, j])
        ax.plot(t, tau[:, j], color="k", lw=1.6, label="measured")
        for method, pred in window["predictions"].items():
            ax.plot(t, np.asarray(pred, dtype=float)[:, j], color=COLORS.get(method), lw=1.1,
                    label=LABELS.get(method, method))
        ax.set_title(name)
        ax.set_xlabel("time [s]")
        ax.grid(True, alpha=0.3)
    for ax in first:
        ax.set_ylabel("torque [N m]")
    axes[0].legend(fontsize=8)
    fig.suptitle(title or "measured and predicted torque (grey: dead zone)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=120)


METRIC_AXIS = {"mse": "test MSE [(N m)$^2$]", "rmse": "test RMSE [N m]", "nmse": "test normalised MSE"}


def _tick(v, _pos=None) -> str:
    """A log axis' tick as a plain number where it is short ('0.002', '50'), else '2e-5'."""
    if not np.isfinite(v) or v <= 0:
        return ""
    if 1e-4 <= v < 1e5:
        return f"{v:g}"
    mantissa, exponent = f"{v:.0e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def change_text(v: float, ref: float) -> str:
    """The change of `v` against `ref` as a percentage: '-90%', '+12%', '-99.6%' ('' when undefined)."""
    if not (np.isfinite(v) and np.isfinite(ref)) or ref <= 0:
        return ""
    pct = 100 * (v / ref - 1)
    if -100 < pct < -99 or 0 < abs(pct) < 1:
        return f"{pct:+.1f}%"
    return f"{pct:+.0f}%"


def comparison_figure(c: Comparison, metric: str = "mse") -> Figure:
    """The comparison chart as a matplotlib figure (the caller closes it): joints on the x axis, in each
    joint's group one bar per model in the given order, the same colour for a model in every group, a
    log axis of the test metric, the change against the first model above every later bar."""
    from .compare import legend_names

    names = legend_names(c)
    joints, M = list(c.joints), len(c.models)
    values = np.array([[s.test[metric][j] for j in joints] for s in c.models], dtype=float)  # (M, J)
    positive = values[np.isfinite(values) & (values > 0)]
    lo, hi = (positive.min(), positive.max()) if positive.size else (1e-3, 1.0)
    bottom, top = lo / 3, hi * 4  # the smallest bar stays half a decade tall; room for the labels
    shown = np.where(np.isfinite(values), np.maximum(values, bottom), np.nan)

    width = max(7.0, min(16.0, 1.2 + len(joints) * (0.5 * M + 0.7)))
    fig, ax = plt.subplots(figsize=(width, 4.6))
    cmap = plt.get_cmap("tab10" if M <= 10 else "tab20")
    colors = [cmap(i % cmap.N) for i in range(M)]
    x = np.arange(len(joints))
    bar_w = 0.8 / M
    for i, (name, row) in enumerate(zip(names, shown)):
        xs = x - 0.4 + bar_w * (i + 0.5)
        ax.bar(xs, row, width=bar_w, color=colors[i], edgecolor="white", linewidth=0.6, label=name,
               zorder=2)
        for k, (xk, v, raw) in enumerate(zip(xs, row, values[i])):
            if not np.isfinite(raw):
                text = "n/a"
            elif M == 1:
                continue
            elif i == 0:
                text = "ref"
            else:
                text = change_text(raw, values[0, k])
            ax.annotate(text, (xk, v if np.isfinite(v) else bottom), xytext=(0, 2),
                        textcoords="offset points", ha="center", va="bottom", fontsize=9 if M <= 4 else 8,
                        color="0.35" if i == 0 else "black", rotation=0 if M <= 5 else 90)

    ax.set_yscale("log")
    ax.set_ylim(bottom, top)
    subs = (1.0, 2.0, 5.0) if np.log10(top / bottom) <= 3.5 else (1.0,)
    ax.yaxis.set_major_locator(ticker.LogLocator(base=10, subs=subs))
    ax.yaxis.set_major_formatter(ticker.FuncFormatter(_tick))
    ax.yaxis.set_minor_locator(ticker.LogLocator(base=10, subs="auto"))
    ax.yaxis.set_minor_formatter(ticker.NullFormatter())
    ax.set_xticks(x, joints)
    ax.set_xlim(-0.6, len(joints) - 0.4)
    ax.tick_params(axis="x", labelsize=11, length=0)
    ax.tick_params(axis="y", labelsize=10)
    ax.set_ylabel(f"{METRIC_AXIS[metric]}, log scale", fontsize=11)
    ax.grid(True, axis="y", which="major", alpha=0.35, zorder=0)
    ax.grid(True, axis="y", which="minor", alpha=0.12, zorder=0)
    ax.set_axisbelow(True)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)

    counts = sorted({s.n_test for s in c.models})
    samples = (f"the same {counts[0]} held-out samples" if len(counts) == 1
               else f"{counts[0]}\u2013{counts[-1]} held-out samples")
    what = "model" if M == 1 else f"{M} models"
    fig.suptitle(f"Held-out test {metric.upper()} per joint: {what} on {samples}", fontsize=13)
    ax.set_title("lower is better" + ("; on each bar the change against model 1" if M > 1 else ""),
                 fontsize=10, color="0.3")
    ncol = 1 if max(map(len, names)) > 34 or M == 1 else min(M, 3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=ncol, frameon=False, fontsize=10,
              handlelength=1.2)
    fig.tight_layout()
    return fig


def plot_comparison(c: Comparison, path: Path | str, metric: str = "mse") -> Path:
    """Write comparison_figure(c, metric) to the PNG `path`."""
    return save_figure(comparison_figure(c, metric), path, dpi=110, bbox_inches="tight")
