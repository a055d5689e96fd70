"""The sweep's verdict on the dead-zone loss, per joint: at how many sizes mlp-masked's mean test MSE is
below mlp-mse's, and how much data the plain loss needs to match the masked loss.

    .venv/bin/python scripts/masked_vs_mse.py out/seven/sweep/results.json [--markdown]

The data factor of a joint: the smallest size at which mlp-mse's mean test MSE is at or below
mlp-masked's at the smallest size, divided by that smallest size ("> F" when mlp-mse never gets there
within the sweep: F = largest size / smallest size).
"""

from __future__ import annotations

import json
import sys

import numpy as np


def verdict(results: dict) -> list[dict]:
    sizes = np.array(results["sizes"], dtype=float)
    masked = np.array(results["methods"]["mlp-masked"]["mse_mean"])
    mse = np.array(results["methods"]["mlp-mse"]["mse_mean"])
    rows = []
    for j, joint in enumerate(results["joints"]):
        below = int(np.sum(masked[:, j] < mse[:, j]))
        reach = np.flatnonzero(mse[:, j] <= masked[0, j])
        factor = (f"{sizes[reach[0]] / sizes[0]:.0f}x ({sizes[reach[0]]:.0f} samples)" if reach.size
                  else f"> {sizes[-1] / sizes[0]:.0f}x (not within {sizes[-1]:.0f})")
        rows.append({"joint": joint, "masked_below": below, "sizes": len(sizes), "factor": factor,
                     "masked_300": masked[0, j], "mse_300": mse[0, j], "masked_max": masked[-1, j],
                     "mse_max": mse[-1, j]})
    return rows


def main(argv: list[str]) -> None:
    rows = verdict(json.loads(open(argv[0]).read()))
    wins = sum(r["masked_below"] == r["sizes"] for r in rows)
    if "--markdown" in argv:
        print("| joint | mlp-masked below mlp-mse | MSE at 300: masked / mse | at 3000: masked / mse | "
              "samples mlp-mse needs to match mlp-masked at the smallest size |")
        print("|---|---|---|---|---|")
    for r in rows:
        cells = (r["joint"], f"{r['masked_below']} of {r['sizes']} sizes",
                 f"{r['masked_300']:.3g} / {r['mse_300']:.3g}", f"{r['masked_max']:.3g} / {r['mse_max']:.3g}",
                 r["factor"])
        markdown = "--markdown" in argv
        print("| " + " | ".join(cells) + " |" if markdown else "  ".join(f"{c:<28}" for c in cells))
    print(f"\nmlp-masked below mlp-mse at every size on {wins} of {len(rows)} joints")


if __name__ == "__main__":
    main(sys.argv[1:])
