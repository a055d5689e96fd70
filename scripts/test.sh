#!/usr/bin/env bash
# Set up (if needed), then lint with ruff and run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
echo "== ruff"
.venv/bin/ruff check .
# one pytest worker per core, at most 4 (PYTEST_WORKERS overrides; 1 runs in this process), each test
# module on one worker so that its shared fixtures are built once
workers=${PYTEST_WORKERS:-$(nproc 2>/dev/null || echo 1)}
[ "$workers" -gt 4 ] && workers=4
echo "== pytest ($workers workers)"
if [ "$workers" -gt 1 ]; then
    .venv/bin/python -m pytest -q -n "$workers" --dist loadfile "$@"
else
    .venv/bin/python -m pytest -q "$@"
fi
