#!/usr/bin/env bash
# Create .venv, install crane-x7 with its dev tools and the live-view extra, compile the numba kernels. The CPU build of torch 2.13.0 is pinned
# through constraints.txt (an unpinned torch would pull several GB of CUDA packages).
# Idempotent: re-running after a change to pyproject.toml or constraints.txt re-installs; the kernels load from cache.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    echo "== creating .venv with $($PY --version)"
    "$PY" -m venv .venv
fi
stamp=.venv/.crane-x7-installed
want=$(cat pyproject.toml constraints.txt | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    echo "== installing crane-x7 and its dependencies (CPU torch pinned by constraints.txt)"
    log=.venv/install.log
    if ! .venv/bin/python -m pip install -c constraints.txt -e ".[dev,view]" > "$log" 2>&1; then
        tail -n 40 "$log"
        echo "Error: installing the dependencies failed (full log: $log)" >&2
        exit 1
    fi
    echo "$want" > "$stamp"
fi
# the numba kernels compiled once, so that no command pays it (about 30 s after an install; a second or two
# when numba's cache has them; collect/kernels.py)
.venv/bin/python -m collect.kernels
