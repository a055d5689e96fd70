#!/usr/bin/env bash
# The main job on the simulated arm, end to end: set up, collect a 10-minute bilateral session from two
# simulated CRANE-X7s, reproduce the paper's sample-size sweep, then the modelling loop: fit a
# rigid-body model, report where it fails, diagnose what is missing, add it, and compare the models.
# Results land in out/ (or $OUT). Environment: DURATION (simulated s, default 600), SEED (default 1).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
BIN=.venv/bin
OUT=${OUT:-out}
DURATION=${DURATION:-600}
SEED=${SEED:-1}
S="$OUT/session.h5"
mkdir -p "$OUT"

echo "== 1/7 collect: ${DURATION} s of 4-channel bilateral control on two simulated arms (lockstep)"
$BIN/crane-collect run --sim --seed "$SEED" --duration "$DURATION" -o "$S" --force

echo "== 2/7 what the session holds"
$BIN/crane-train info "$S"

echo "== 3/7 the paper's sweep: rigid-body, mlp-mse, mlp-masked over 10 training-set sizes, 10 trials each"
echo "   (the paper's 300..3000 samples, scaled down to the data if the session is shorter: the sweep says so)"
echo "   runs beside steps 4-7, which need only the session; its log is $OUT/sweep.log, shown when it ends"
# The sweep trains on one core; the modelling loop below uses the other (on one core both still finish).
$BIN/crane-train sweep "$S" -o "$OUT/sweep" --seed "$SEED" --scale-to-data --force > "$OUT/sweep.log" 2>&1 &
sweep_pid=$!
trap 'kill "$sweep_pid" 2> /dev/null || true' EXIT

echo "== 4/7 a rigid-body (Newton-Euler) model of the follower"
$BIN/crane-train fit "$S" --model rigid-body -o "$OUT/models/rigid-body" --seed "$SEED" --scale-to-data --force

echo "== 5/7 where does it fail? (HTML report) and which physical effect is missing? (diagnose)"
$BIN/crane-train report "$OUT/models/rigid-body" "$S" -o "$OUT/report-rigid-body.html" --force
$BIN/crane-train diagnose "$OUT/models/rigid-body" "$S" --json-out "$OUT/diagnosis.json" --force

echo "== 6/7 add what the diagnosis names (Coulomb and viscous friction), and the networks"
$BIN/crane-train fit "$S" --model rigid-body --effect coulomb --effect viscous \
    -o "$OUT/models/rigid-body+friction" --seed "$SEED" --scale-to-data --force
$BIN/crane-train fit "$S" --model mlp-masked -o "$OUT/models/mlp-masked" --seed "$SEED" --scale-to-data --force
$BIN/crane-train fit "$S" --model hybrid --effect coulomb --effect viscous \
    -o "$OUT/models/hybrid" --seed "$SEED" --scale-to-data --force

echo "== 7/7 watch the error fall"
$BIN/crane-train compare "$OUT/models/rigid-body" "$OUT/models/rigid-body+friction" \
    "$OUT/models/mlp-masked" "$OUT/models/hybrid" -o "$OUT/compare.png" --force

echo "== 3/7 (the sweep, run beside 4-7)"
if ! wait "$sweep_pid"; then
    cat "$OUT/sweep.log"
    echo "Error: the sweep failed (its log: $OUT/sweep.log)" >&2
    exit 1
fi
trap - EXIT
cat "$OUT/sweep.log"

echo
echo "Done. In $OUT/: sweep/ (results.json, results.csv, mse_vs_samples.png, window_torque.png), sweep.log,"
echo "report-rigid-body.html, diagnosis.json, models/, compare.png."
