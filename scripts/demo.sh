#!/usr/bin/env bash
# The main job on the simulated arm, end to end: set up, collect a 10-minute bilateral session from two
# simulated CRANE-X7s, reproduce the paper's sample-size sweep, then the modelling loop (fit a
# rigid-body model, report where it fails, diagnose what is missing). Results land in out/.
# Options (environment): DURATION (simulated seconds, default 600), SEED (default 1), OUT (default out).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
BIN=.venv/bin
OUT=${OUT:-out}
DURATION=${DURATION:-600}
SEED=${SEED:-1}
mkdir -p "$OUT"

echo "== 1/6 collect: ${DURATION} s of 4-channel bilateral control on two simulated arms"
$BIN/crane-collect run --sim --seed "$SEED" --duration "$DURATION" -o "$OUT/session.h5" --force

echo "== 2/6 what the session holds"
$BIN/crane-train info "$OUT/session.h5"

echo "== 3/6 the paper's sweep: rigid-body, mlp-mse, mlp-masked over 300..3000 samples, 10 trials"
$BIN/crane-train sweep "$OUT/session.h5" -o "$OUT/sweep" --seed "$SEED"

echo "== 4/6 fit a rigid-body model on the session"
$BIN/crane-train fit "$OUT/session.h5" --model rigid-body -o "$OUT/models/rigid-body" --seed "$SEED"

echo "== 5/6 where does it fail? (report) and what is missing? (diagnose)"
$BIN/crane-train report "$OUT/models/rigid-body" "$OUT/session.h5" -o "$OUT/report-rigid-body.html"
$BIN/crane-train diagnose "$OUT/models/rigid-body" "$OUT/session.h5"

echo "== 6/6 the masked network for comparison"
$BIN/crane-train fit "$OUT/session.h5" --model mlp-masked -o "$OUT/models/mlp-masked" --seed "$SEED"
$BIN/crane-train compare "$OUT/models/rigid-body" "$OUT/models/mlp-masked" --session "$OUT/session.h5" \
    -o "$OUT/compare.png"

echo
echo "Done. Open $OUT/sweep/ (results.json, figures) and $OUT/report-rigid-body.html."
