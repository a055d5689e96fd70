"""The product's functions stay simple: at most MAX_OVER functions of crane_io, collect and train have a
McCabe complexity over 10 (ruff's C901; pyproject.toml makes ruff refuse any over 20)."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("crane_io", "collect", "train")
THRESHOLD = 10
MAX_OVER = 15


def _over_threshold() -> list[str]:
    """ruff's C901 findings at THRESHOLD over the packages, one line each."""
    ruff = Path(sys.executable).parent / "ruff"
    assert ruff.exists(), f"ruff is not installed next to {sys.executable}"
    proc = subprocess.run(
        [str(ruff), "check", "--no-cache", "--select", "C901", "--config",
         f"lint.mccabe.max-complexity={THRESHOLD}", "--output-format", "concise", *PACKAGES],
        cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode in (0, 1), f"ruff failed: {proc.stderr.strip()}"
    found = [line for line in proc.stdout.splitlines() if re.search(r"\bC901\b", line)]
    assert (proc.returncode == 1) == bool(found), f"ruff's output was not understood:\n{proc.stdout}"
    return found


def test_at_most_fifteen_functions_have_a_complexity_over_ten():
    over = _over_threshold()
    print(f"{len(over)} functions over complexity {THRESHOLD}:", *over, sep="\n")
    assert len(over) <= MAX_OVER, (f"{len(over)} functions have a McCabe complexity over {THRESHOLD} (at "
                                   f"most {MAX_OVER} may); split the new ones into functions with one job "
                                   "each:\n" + "\n".join(over))
