"""Run the project's benchmarks and print one table.

    .venv/bin/python benchmarks/run_all.py            # every benchmarks/bench_*.py
    .venv/bin/python benchmarks/run_all.py bus        # only bench_bus.py (names with or without bench_)
    .venv/bin/python benchmarks/run_all.py --quick    # a smoke run: small sizes, seconds not minutes
    .venv/bin/python benchmarks/run_all.py --json out/bench.json
    .venv/bin/python benchmarks/run_all.py --markdown out/bench.md   # the table with its conditions

Each benchmarks/bench_NAME.py exposes `run(quick: bool) -> list[dict]`; every row has the keys
benchmark, metric, value, unit, note. A benchmark that raises is reported as a FAILED row and makes the
exit status non-zero; the others still run.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
KEYS = ("benchmark", "metric", "value", "unit", "note")


def discover(folder: Path = HERE) -> dict[str, Path]:
    """Short name ('bus') -> file, for every bench_*.py in `folder`, sorted by name."""
    return {p.stem[len("bench_"):]: p for p in sorted(folder.glob("bench_*.py"))}


def load(path: Path):
    spec = importlib.util.spec_from_file_location(f"crane_bench_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    if not callable(getattr(module, "run", None)):
        raise TypeError(f"{path.name} has no run(quick) function")
    return module


def run_one(name: str, path: Path, quick: bool) -> list[dict]:
    start = time.perf_counter()
    try:
        rows = list(load(path).run(quick))
    except Exception as exc:  # noqa: BLE001 - a broken benchmark must not stop the others
        traceback.print_exc(file=sys.stderr)
        return [{"benchmark": name, "metric": "FAILED", "value": float("nan"), "unit": "",
                 "note": f"{type(exc).__name__}: {exc}"}]
    for row in rows:
        missing = [k for k in KEYS if k not in row]
        if missing:
            raise ValueError(f"bench_{name}.py returned a row without {', '.join(missing)}: {row}")
    rows.append({"benchmark": name, "metric": "wall time", "value": time.perf_counter() - start,
                 "unit": "s", "note": "quick" if quick else ""})
    return rows


def fmt_value(value) -> str:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    if isinstance(value, int):
        return f"{value:d}"
    if math.isnan(value):
        return "nan"
    if value != 0 and (abs(value) >= 1e5 or abs(value) < 1e-3):
        return f"{value:.3e}"
    return f"{value:.4g}" if abs(value) < 100 else f"{value:.1f}"


def table(rows: list[dict]) -> str:
    """Rows as an aligned text table (value right-aligned)."""
    cells = [[str(r["benchmark"]), str(r["metric"]), fmt_value(r["value"]), str(r["unit"]), str(r["note"])]
             for r in rows]
    head = ["benchmark", "metric", "value", "unit", "note"]
    widths = [max(len(x) for x in col) for col in zip(head, *cells)]
    line = "  ".join("-" * w for w in widths)

    def fmt(c):
        padded = (c[i].rjust(widths[i]) if i == 2 else c[i].ljust(widths[i]) for i in range(5))
        return "  ".join(padded).rstrip()

    return "\n".join([fmt(head), line] + [fmt(c) for c in cells])


def conditions(start_load: tuple[float, float, float]) -> list[str]:
    """What a reader needs to weigh the figures: date, commit, machine, load before and after."""
    import os
    import platform
    import subprocess

    try:
        commit = subprocess.run(["git", "-C", str(HERE), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        commit = "unknown"
    end_load = os.getloadavg()
    return [f"- date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; commit {commit}",
            f"- machine: {platform.machine()}, {os.cpu_count()} logical CPUs, {platform.system()} "
            f"{platform.release()}, Python {platform.python_version()}",
            f"- load average (1, 5, 15 min): {', '.join(f'{x:.1f}' for x in start_load)} before, "
            f"{', '.join(f'{x:.1f}' for x in end_load)} after"]


def markdown(rows: list[dict], start_load: tuple[float, float, float], quick: bool) -> str:
    """The rows as a Markdown table under the conditions they were measured in."""
    command = ".venv/bin/python benchmarks/run_all.py" + (" --quick" if quick else "")
    lines = [f"Measured with `{command}`:", "", *conditions(start_load), "",
             "| benchmark | metric | value | unit | note |", "|---|---|---:|---|---|"]
    for r in rows:
        cells = [str(r["benchmark"]), str(r["metric"]), fmt_value(r["value"]), str(r["unit"]), str(r["note"])]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Run benchmarks/bench_*.py and print one table.")
    parser.add_argument("names", nargs="*", help="benchmarks to run (default: all), e.g. bus")
    parser.add_argument("--quick", action="store_true", help="small sizes: a smoke run")
    parser.add_argument("--json", metavar="FILE", help="also write the rows as JSON to FILE")
    parser.add_argument("--markdown", metavar="FILE", help="also write the rows as a Markdown table with the "
                        "date, commit, machine and load to FILE")
    args = parser.parse_args(argv)
    import os

    start_load = os.getloadavg()

    found = discover()
    wanted = [n[len("bench_"):] if n.startswith("bench_") else n for n in args.names]
    wanted = [n[:-3] if n.endswith(".py") else n for n in wanted]
    unknown = [n for n in wanted if n not in found]
    if unknown:
        print(f"Error: no benchmark named {', '.join(unknown)} (have: {', '.join(found) or 'none'})",
              file=sys.stderr)
        return 2
    rows: list[dict] = []
    for name in wanted or list(found):
        print(f"running bench_{name} ...", file=sys.stderr, flush=True)
        rows.extend(run_one(name, found[name], args.quick))
    print(table(rows))
    if args.json:
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(rows, indent=2, default=float))
    if args.markdown:
        out = Path(args.markdown)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(markdown(rows, start_load, args.quick))
    return 1 if any(r["metric"] == "FAILED" for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
