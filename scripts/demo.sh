#!/usr/bin/env bash
# The main job on the bundled fixtures: simulate every conformance recording from its
# voltage and parameters, and report how closely the trace is reproduced.
set -euo pipefail
BIN=${1:-.venv/bin}
OUT=out/demo
mkdir -p "$OUT"
for rec in fixtures/reference/ref_*.csv; do
  name=$(basename "$rec" .csv)
  "$BIN/stickslip" simulate --params fixtures/reference/params.json --voltage-from "$rec" \
    --out "$OUT/$name.sim.csv" --plot "$OUT/$name.png" --force
done
"$BIN/python" scripts/compare_traces.py fixtures/reference "$OUT"
