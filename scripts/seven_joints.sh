#!/usr/bin/env bash
# Seven joints (docs/results.md "Seven joints"): bilateral control of the whole arm on the simulated CRANE-X7,
# the paper's sweep at seven joints, and planted effects on the wrist.
#
# 1. a ${DURATION} s session with every arm joint bilateral (crane-x7-7dof plant), what it holds (moving
#    fractions per joint and for all seven together), and the paper's sweep over the seven joints
#    (validation and test sets per joint: see docs/train.md);
# 2. per planted wrist preset (hidden-wrist-coulomb: Coulomb on joint6; hidden-wrist-spring: a spring on
#    joint5): a ${PLANTED_S} s session, the baseline model (rigid body + the preset's [known] effects),
#    diagnose, the model with the named effect, compare.
# Results land in $OUT (default out/seven): info.txt, sweep/, planted-*/ (diagnosis.json, compare.json).
# Environment: DURATION (simulated s, default 600), PLANTED_S (default 300), SEED (default 1); REUSE=1
# keeps the sessions already in $OUT (re-runs the training steps only).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
BIN=.venv/bin
OUT=${OUT:-out/seven}
DURATION=${DURATION:-600}
PLANTED_S=${PLANTED_S:-300}
SEED=${SEED:-1}
mkdir -p "$OUT"
S="$OUT/session.h5"
# have PATH: with REUSE=1, PATH exists already (skip the step that makes it)
have() { [ -n "${REUSE:-}" ] && [ -e "$1" ]; }

echo "== 1/3 collect: ${DURATION} s of 4-channel bilateral control of all seven joints (lockstep)"
have "$S" || $BIN/crane-collect run --sim --joints all --seed "$SEED" --duration "$DURATION" -o "$S" --force
$BIN/crane-train info "$S" --joints all | tee "$OUT/info.txt"

echo "== 2/3 the paper's sweep at seven joints: rigid-body, mlp-mse, mlp-masked, 10 sizes x 10 trials"
$BIN/crane-train sweep "$S" --joints all -o "$OUT/sweep" --seed "$SEED" --scale-to-data --no-progress --force

$BIN/python scripts/masked_vs_mse.py "$OUT/sweep/results.json" --markdown | tee "$OUT/masked_vs_mse.md"

echo "== 3/3 planted effects on the wrist"
for preset in hidden-wrist-coulomb hidden-wrist-spring; do
    P="$OUT/planted-$preset"
    mkdir -p "$P"
    have "$P/session.h5" ||
        $BIN/crane-collect run --sim --joints all --plant "$preset" --seed "$SEED" --duration "$PLANTED_S" \
            -o "$P/session.h5" --force --quiet
    # the baseline model is told what the preset's [known] table lists; the hidden effect is not in it
    read -r -a KNOWN <<< "$($BIN/python -c "
from crane_io.sim.plant_config import load_plant_config
print(' '.join(f'--effect {n}:joint={j}' for n, j, _ in load_plant_config('$preset').known))")"
    HIDDEN=$($BIN/python -c "
from crane_io.sim.plant_config import load_plant_config
h = load_plant_config('$preset').hidden
print(f'{h.effect}:joint={h.joint}')")
    FIT="$BIN/crane-train fit $P/session.h5 --joints all --model rigid-body --scale-to-data --no-progress --force"
    $FIT "${KNOWN[@]}" -o "$P/baseline" --seed "$SEED"
    $BIN/crane-train diagnose "$P/baseline" "$P/session.h5" | tee "$P/diagnosis.txt"
    $BIN/crane-train diagnose "$P/baseline" "$P/session.h5" --json > "$P/diagnosis.json"
    $FIT "${KNOWN[@]}" --effect "$HIDDEN" -o "$P/with-effect" --seed "$SEED"
    $BIN/crane-train compare "$P/baseline" "$P/with-effect" | tee "$P/compare.txt"
    $BIN/crane-train compare "$P/baseline" "$P/with-effect" --json > "$P/compare.json"
done
echo
echo "Done. In $OUT/: info.txt, sweep/ (results.json, results.csv, mse_vs_samples.png), planted-*/."
