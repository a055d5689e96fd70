"""The "Closing the loop" tables of docs/results.md from the fidelity JSON files of
scripts/closing-the-loop.sh.

    python scripts/fidelity_table.py out/loop      # prints Markdown tables
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

JOINTS = ("joint1", "joint2", "joint4")
MODELS = ("nominal", "rigid-body", "rigid-body+friction", "mlp-masked", "hybrid", "hybrid-both-arms",
          # step 5, the follower's friction dither (ratios against "nominal": no dither, same run)
          "nominal+dither", "rigid-body+friction+dither-sign", "rigid-body+friction+dither",
          "rigid-body+friction+dither-observer", "rigid-body+friction+dither-c40")
HIDDEN = ("nominal", "hc-baseline", "hc-with-coulomb")


def _load(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None


def _cells(docs: dict, key: str, fmt: str = "{:.3f}", ratio_to: str | None = "nominal") -> list[str]:
    rows = []
    for name, doc in docs.items():
        cells = []
        for j in JOINTS:
            v = doc["joints"].get(j, {}).get(key)
            text = "-" if v is None else fmt.format(v)
            base = docs.get(ratio_to, {}).get("joints", {}).get(j, {}).get(key) if ratio_to else None
            if ratio_to and name != ratio_to and v and base:
                text += f" ({base / v:.1f}x)"
            cells.append(text)
        rows.append(f"| {name} | " + " | ".join(cells) + " |")
    return rows


def table(title: str, docs: dict, key: str, fmt: str = "{:.3f}", ratio: bool = True) -> str:
    head = [f"**{title}**", "", "| observers | " + " | ".join(JOINTS) + " |", "|---|" + "---|" * len(JOINTS)]
    return "\n".join(head + _cells(docs, key, fmt, "nominal" if ratio else None)) + "\n"


def main(out: str) -> None:
    folder = Path(out)
    docs = {m: d for m in MODELS if (d := _load(folder / f"fidelity-{m}.json")) is not None}
    if docs:
        any_doc = next(iter(docs.values()))
        print(f"Evaluation: {any_doc['free_s']:.0f} s of free motion and {any_doc['contact_s']:.0f} s of "
              f"contact (nominal run); RMS in N m unless stated, (Nx) = nominal / model.\n")
        print(table("Free motion, joint moving: follower tau_res (false force)", docs,
                    "follower_false_rms_moving"))
        print(table("Free motion, joint standing still: follower tau_res", docs, "follower_false_rms_still"))
        print(table("Free motion, all samples: follower tau_res", docs, "follower_false_rms"))
        print(table("Free motion: the hand's true torque (what the operator pushes)", docs, "hand_true_rms"))
        print(table("Contact: estimate error / true contact torque RMS", docs, "contact_error_ratio",
                    "{:.1%}", ratio=False))
        print(table("Force channel: leader + follower tau_res", docs, "force_sum_rms", ratio=False))
        print(table("Position tracking RMS (deg)", docs, "tracking_rms_deg", "{:.3f}", ratio=False))
    hidden = {m: d for m in HIDDEN if (d := _load(folder / f"hc-fidelity-{m}.json")) is not None}
    if hidden:
        print(table("hidden-coulomb, free motion, joint moving: follower tau_res", hidden,
                    "follower_false_rms_moving"))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out/loop")
