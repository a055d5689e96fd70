"""`crane-train report`: one self-contained HTML page showing where a model fails.

Everything is evaluated on held-out data (train.evaluation.heldout): per joint, measured and predicted torque
over the plotting window with dead-zone periods shaded, the residual over time, the residual against angle,
velocity and acceleration (binned means with 95 % intervals), the error split by region (moving / dead
zone, velocity bands, angle bands) and a summary table of MSE, RMSE and normalised MSE. Figures are
matplotlib PNGs embedded as base64; the CSS is inline; the page references no external URL, so it
opens offline.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..models.recorded_effects import effect_labels
from .heldout import HeldOut

if TYPE_CHECKING:
    from collections.abc import Sequence

    from matplotlib.figure import Figure

    from ..diagnosis.discovery import Discovery, JointDiscovery
    from ..diagnosis.result import Diagnosis
    from ..models.base import Model

CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 2em auto;
       max-width: 1100px; color: #222; line-height: 1.4; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; margin-top: 2em; }
h3 { margin-top: 1.5em; }
table { border-collapse: collapse; margin: .8em 0; font-size: .92em; }
th, td { border: 1px solid #ccc; padding: .25em .6em; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
.note { background: #f7f7ee; border-left: 4px solid #cc9; padding: .5em 1em; }
img { max-width: 100%; } .meta td { text-align: left; }
"""


# ---- numbers ----------------------------------------------------------------------------------------

def error_stats(measured: np.ndarray, predicted: np.ndarray) -> dict:
    """MSE (N m^2), RMSE (N m), normalised MSE (MSE / variance of the measured torque) of 1-D arrays."""
    measured = np.asarray(measured, float)
    err = measured - np.asarray(predicted, float)
    n = len(err)
    if n == 0:
        return {"n": 0, "mse": float("nan"), "rmse": float("nan"), "nmse": float("nan")}
    mse = float(np.mean(err ** 2))
    var = float(np.var(measured))
    return {"n": n, "mse": mse, "rmse": float(np.sqrt(mse)), "nmse": mse / var if var > 0 else float("nan")}


def binned_means(x: np.ndarray, y: np.ndarray, bins: int = 12, min_count: int = 5
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean of y in quantile bins of x with a 95 % interval (normal approximation, independent samples).

    Returns (centres, means, half_widths, counts) for the bins holding at least `min_count` samples.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) == 0:
        return (np.array([]),) * 4
    edges = np.unique(np.quantile(x, np.linspace(0, 1, bins + 1)))
    if len(edges) < 2:
        edges = np.array([x.min() - 0.5, x.max() + 0.5])
    which = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    centres, means, half, counts = [], [], [], []
    for b in range(len(edges) - 1):
        sel = which == b
        n = int(sel.sum())
        if n < min_count:
            continue
        centres.append(float(np.mean(x[sel])))
        means.append(float(np.mean(y[sel])))
        half.append(float(1.96 * np.std(y[sel], ddof=1) / np.sqrt(n)))
        counts.append(n)
    return np.array(centres), np.array(means), np.array(half), np.array(counts)


def region_table(held: HeldOut, pred: np.ndarray, j: int) -> list[dict]:
    """Error of joint j split by region: moving / dead zone, |velocity| tertiles, angle tertiles."""
    ds = held.data
    tau, p = ds.tau[:, j], pred[:, j]
    moving = ds.moving[:, j]
    sq = (tau - p) ** 2
    total = float(sq.sum()) or 1.0
    rows = []

    def add(group, label, sel):
        s = error_stats(tau[sel], p[sel])
        s.update(group=group, region=label, share=float(sq[sel].sum() / total))
        rows.append(s)

    add("motion", "moving", moving)
    add("motion", "dead zone (standing still)", ~moving)
    speed = np.abs(ds.dq[:, j])
    if moving.sum() >= 3:
        lo, hi = np.quantile(speed[moving], [1 / 3, 2 / 3])
        add("speed (moving samples)", f"|dq| < {lo:.2f} rad/s", moving & (speed < lo))
        add("speed (moving samples)", f"{lo:.2f} ≤ |dq| < {hi:.2f} rad/s",
            moving & (speed >= lo) & (speed < hi))
        add("speed (moving samples)", f"|dq| ≥ {hi:.2f} rad/s", moving & (speed >= hi))
    q = ds.q[:, j]
    lo, hi = np.quantile(q, [1 / 3, 2 / 3])
    add("angle (all samples)", f"q < {lo:.2f} rad", q < lo)
    add("angle (all samples)", f"{lo:.2f} ≤ q < {hi:.2f} rad", (q >= lo) & (q < hi))
    add("angle (all samples)", f"q ≥ {hi:.2f} rad", q >= hi)
    return rows


def summary_rows(held: HeldOut, pred: np.ndarray) -> list[dict]:
    """Per joint: on the test samples (every joint moves, as the paper) and on all held-out samples
    where that joint moves."""
    ds = held.data
    out = []
    for j, name in enumerate(ds.joint_names):
        rows = held.test_rows(j) if hasattr(held, "test_rows") else held.test
        test = error_stats(ds.tau[rows, j], pred[rows, j])
        mov = held.moving_rows(j)
        moving = error_stats(ds.tau[mov, j], pred[mov, j])
        out.append({"joint": name, "test": test, "moving": moving})
    return out


# ---- figures ----------------------------------------------------------------------------------------

def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _shade_dead_zones(ax, t, moving):
    """Grey spans where the joint stands still (its dead-zone mask is False)."""
    still = ~np.asarray(moving, bool)
    if not still.any():
        return
    dt = np.median(np.diff(t)) if len(t) > 1 else 0.02
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(int), 0]))
    for a, b in zip(edges[::2], edges[1::2]):
        ax.axvspan(t[a] - dt / 2, t[b - 1] + dt / 2, color="0.85", lw=0, zorder=0)


def figure_time(held: HeldOut, pred: np.ndarray, j: int) -> Figure:
    """Top: measured and predicted torque over the window, dead zones shaded. Bottom: residual over
    time for all held-out samples."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ds = held.data
    name = ds.joint_names[j]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 5.2), gridspec_kw={"height_ratios": [3, 2]})
    w = held.window
    t = ds.t[w]
    if len(t):
        _shade_dead_zones(ax1, t, ds.moving[w, j])
        ax1.plot(t, ds.tau[w, j], color="k", lw=1.4, label="measured")
        ax1.plot(t, pred[w, j], color="tab:red", lw=1.2, ls="--", label="predicted")
    ax1.set_ylabel(f"{name} torque [N m]")
    ax1.set_xlabel("time [s] (grey: dead zone, the joint stands still)")
    ax1.set_title(f"{name}: measured vs predicted over the held-out window")
    ax1.legend(loc="upper right", fontsize=8)
    res = ds.tau[:, j] - pred[:, j]
    mov = ds.moving[:, j]
    x = np.arange(len(ds))  # held-out blocks are not contiguous in time: plot against sample order
    ax2.plot(x[~mov], res[~mov], ".", ms=2, color="0.6", label="dead zone")
    ax2.plot(x[mov], res[mov], ".", ms=2, color="tab:blue", label="moving")
    ax2.axhline(0, color="k", lw=0.8)
    for b in held.block_starts[1:]:
        ax2.axvline(b, color="0.7", lw=0.6, ls=":")
    ax2.set_ylabel("residual [N m]")
    ax2.set_xlabel("held-out sample (dotted lines: a new held-out block)")
    ax2.legend(loc="upper right", fontsize=8, markerscale=4)
    fig.tight_layout()
    return fig


def figure_binned(held: HeldOut, pred: np.ndarray, j: int) -> Figure:
    """Residual of joint j (samples where it moves) against its angle, velocity and acceleration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ds = held.data
    rows = held.moving_rows(j)
    res = ds.tau[rows, j] - pred[rows, j]
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.3), sharey=True)
    for ax, (label, x) in zip(axes, [("angle [rad]", ds.q[rows, j]), ("velocity [rad/s]", ds.dq[rows, j]),
                                     ("acceleration [rad/s²]", ds.ddq[rows, j])]):
        ax.plot(x, res, ".", ms=1.5, color="0.75", zorder=1)
        c, m, h, _ = binned_means(x, res)
        if len(c):
            ax.errorbar(c, m, yerr=h, fmt="o-", color="tab:blue", ms=4, capsize=3, zorder=2)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xlabel(label)
    axes[0].set_ylabel(f"{ds.joint_names[j]} residual [N m]")
    fig.suptitle(f"{ds.joint_names[j]}: residual (measured − predicted) where the joint moves; "
                 "binned means with 95 % intervals", fontsize=10)
    fig.tight_layout()
    return fig


def figure_discovery(found: JointDiscovery) -> Figure:
    """A discovered expression (train.diagnosis.discovery.JointDiscovery) against the residual it explains
    (what the base model leaves on the joint's moving samples, all of them): left, over a stretch of samples;
    right, residual against the expression's value (on the diagonal when the expression explains it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    c = found.curves
    res, fit = np.asarray(c["residual"]), np.asarray(c["fit"])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.2), gridspec_kw={"width_ratios": [2, 1]})
    n = min(len(res), 600)
    start = max(0, len(res) // 2 - n // 2)
    x = np.arange(start, start + n)
    ax1.plot(x, res[x], ".", ms=2.5, color="0.55", label="residual")
    ax1.plot(x, fit[x], color="tab:red", lw=1.2, label="discovered expression")
    ax1.axhline(0, color="k", lw=0.6)
    ax1.set_xlabel("sample where the joint moves")
    ax1.set_ylabel(f"{found.joint} [N m]")
    ax1.legend(loc="upper right", fontsize=8, markerscale=3)
    ax2.plot(fit, res, ".", ms=1.5, color="tab:blue", alpha=0.5)
    lo, hi = float(min(fit.min(), res.min())), float(max(fit.max(), res.max()))
    ax2.plot([lo, hi], [lo, hi], color="k", lw=0.8)
    ax2.set_xlabel("discovered expression [N m]")
    ax2.set_ylabel("residual [N m]")
    expr = found.expression if len(found.expression) < 70 else found.expression[:67] + "..."
    fig.suptitle(f"{found.joint}: {expr} — removes {100 * found.error_reduction:.0f} % of the held-out "
                 "error", fontsize=10)
    fig.tight_layout()
    return fig


def discovery_section(discovery: Discovery) -> str:
    """HTML of a discovery (train.diagnosis.discovery.Discovery): each joint's sentence, and for every
    significant expression its terms with uncertainties and its fit against the residual."""
    parts = ["<h2 id='discovery'>Discovery</h2><p>A sparse regression of each joint's residual on a "
             "basis of physical terms; the error reduction is measured on time blocks never used to "
             "select or fit the terms (docs/modelling.md, Discovery).</p><ul>"]
    parts += [f"<li>{html.escape(d.sentence)}</li>" for d in discovery.discovered]
    parts.append("</ul>")
    for d in discovery.discovered:
        if not (d.significant and d.curves):
            continue
        parts.append(f"<h3>{html.escape(d.joint)}: {html.escape(d.expression)}</h3>")
        parts.append(_table(["term", "coefficient", "± (jackknife)", "unit"],
                            [[t.term, _num(t.coefficient), _num(t.stderr, 2), t.unit] for t in d.terms]))
        parts.append(f"<img alt='{html.escape(d.joint)} discovered expression against the residual' "
                     f"src='data:image/png;base64,{_png(figure_discovery(d))}'>")
    return "\n".join(parts)


# ---- the page --------------------------------------------------------------------------------------

def _num(v: float, digits=4) -> str:
    if v is None or not np.isfinite(v):
        return "–"
    return f"{v:.{digits}g}"


def _table(head: list[str], rows: list[list]) -> str:
    th = "".join(f"<th>{html.escape(str(h))}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def report_html(model: Model, model_dir: Path | str | None, held: HeldOut,
                sessions: Sequence[Path | str] = (),
                diagnosis: Diagnosis | None = None, discovery: Discovery | None = None) -> str:
    """The report page as a string (with the discovered expressions when `discovery` is given)."""
    ds = held.data
    from ..models.base import predict_on

    pred = np.asarray(predict_on(model, ds), float)
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
             f"<title>crane-x7 model report: {html.escape(str(model_dir))}</title><style>{CSS}</style>"
             f"</head><body>"]
    parts.append(f"<h1>Model report: {html.escape(str(model_dir))}</h1>")
    meta = [["method", model.method], ["joints", ", ".join(ds.joint_names)],
            ["effects in the model", ", ".join(effect_labels(model)) or "none"],
            ["sessions", ", ".join(str(s) for s in sessions) or "–"],
            ["generated", _dt.datetime.now().isoformat(timespec="seconds")]]
    parts.append("<table class='meta'>" + "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(str(v))}"
                                                  f"</td></tr>" for k, v in meta) + "</table>")
    parts.append("<p class='note'><b>Evaluated on held-out data only.</b> "
                 f"{html.escape(held.description)}</p>")

    parts.append("<h2 id='summary'>Summary</h2>")
    rows = []
    for r in summary_rows(held, pred):
        t, m = r["test"], r["moving"]
        rows.append([r["joint"], t["n"], _num(t["mse"]), _num(t["rmse"]), _num(t["nmse"]), m["n"],
                     _num(m["mse"]), _num(m["rmse"]), _num(m["nmse"])])
    parts.append(_table(["joint", "test samples", "MSE [N m²]", "RMSE [N m]", "normalised MSE",
                         "held-out samples where it moves", "MSE [N m²]", "RMSE [N m]", "normalised MSE"],
                        rows))
    parts.append("<p>Test samples: every learning joint moves (the paper's test set). Normalised MSE = "
                 "MSE / variance of the measured torque (1 = no better than predicting the mean).</p>")
    if diagnosis is not None:
        parts.append("<h2 id='diagnosis'>Diagnosis</h2><ul>" + "".join(
            f"<li>{html.escape(s)}</li>" for s in diagnosis.summary.values()) + "</ul>")
    if discovery is not None:
        parts.append(discovery_section(discovery))

    for j, name in enumerate(ds.joint_names):
        parts.append(f"<h2 id='joint-{html.escape(name)}'>{html.escape(name)}</h2>")
        parts.append("<h3>Torque and residual over time</h3>")
        parts.append(f"<img alt='{name} torque over time' src='data:image/png;base64,"
                     f"{_png(figure_time(held, pred, j))}'>")
        parts.append("<h3>Residual against angle, velocity and acceleration</h3>")
        parts.append(f"<img alt='{name} residual against state' src='data:image/png;base64,"
                     f"{_png(figure_binned(held, pred, j))}'>")
        parts.append("<h3>Error by region</h3>")
        reg = region_table(held, pred, j)
        parts.append(_table(["region", "samples", "MSE [N m²]", "RMSE [N m]", "share of squared error"],
                            [[f"{r['group']}: {r['region']}", r["n"], _num(r["mse"]), _num(r["rmse"]),
                              f"{100 * r['share']:.0f} %"] for r in reg]))
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(path: Path | str, page: str) -> Path:
    """Write the page to `path` atomically (crane_io.output_files; a full disk is one sentence)."""
    from crane_io.output_files import write_text_atomic

    return write_text_atomic(path, page, "report")
