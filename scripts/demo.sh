#!/usr/bin/env bash
# The main job on the bundled fixtures:
#  1. simulate every conformance recording from its voltage and parameters, and report
#     how closely the independent implementation's trace is reproduced;
#  2. identify the actuator behind fixtures/identification (17 recordings of the
#     paper's protocol) from the default profile, and compare with the known truth.
# About 1 min on two cores in all (67 s measured 2026-11-26; the README says the same).
set -euo pipefail
BIN=${1:-.venv/bin}
OUT=out/demo
mkdir -p "$OUT"
for rec in fixtures/reference/ref_*.csv; do
  name=$(basename "$rec" .csv)
  "$BIN/stickslip" simulate --params fixtures/reference/params.json --voltage-from "$rec" \
    --out "$OUT/$name.sim.csv" --force
done
# NRMSE per trace, and $OUT/<name>.png: reference (independent implementation) vs simulated
"$BIN/python" scripts/compare_traces.py fixtures/reference "$OUT" --plot

echo
echo "== identify fixtures/identification (most of the demo's minute) =="
"$BIN/stickslip" identify fixtures/identification --out "$OUT/identify" --fix Ms=0.0247 --force
"$BIN/python" scripts/compare_params.py "$OUT/identify/params.json" \
  fixtures/identification/truth.json
