"""benchmarks/run_all.py: discovers bench_*.py, runs them, prints one table, survives a broken one."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import run_all  # noqa: E402


def test_quick_bus_benchmark_prints_a_table_and_json(tmp_path):
    out = tmp_path / "bench.json"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "run_all.py"), "--quick", "bus",
                           "--json", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].split() == ["benchmark", "metric", "value", "unit", "note"]
    rows = json.loads(out.read_text())
    assert all(set(run_all.KEYS) <= set(r) for r in rows)
    metrics = {r["metric"]: r["value"] for r in rows}
    assert metrics["in-process fast: cycles/s"] > 0
    assert metrics["Protocol 2.0 minimum, plain sync read"] == 190 + 38
    # fast sync read + goal currents of the 3 current-mode joints: 22 + 120 + 23 bytes
    assert metrics["wire bytes per cycle (measured)"] == 165


def test_unknown_benchmark_name_is_an_error(capsys):
    assert run_all.main(["nosuchbench"]) == 2
    assert "no benchmark named nosuchbench" in capsys.readouterr().err


def test_a_broken_benchmark_is_a_failed_row_not_a_crash(tmp_path):
    (tmp_path / "bench_broken.py").write_text("def run(quick):\n    raise RuntimeError('boom')\n")
    (tmp_path / "bench_ok.py").write_text(
        "def run(quick):\n    return [dict(benchmark='ok', metric='x', value=1.5, unit='s', note='')]\n")
    found = run_all.discover(tmp_path)
    assert list(found) == ["broken", "ok"]
    rows = run_all.run_one("broken", found["broken"], True) + run_all.run_one("ok", found["ok"], True)
    assert rows[0]["metric"] == "FAILED" and "boom" in rows[0]["note"]
    text = run_all.table(rows)
    assert "FAILED" in text and "1.5" in text
