#!/usr/bin/env bash
# The solver-robust posterior under several between-solver spread floors
# (docs/inference.md#solver-spread), on a finished solver study: for each
# floor, leave-one-solver-out per held-out variant, pooled over them, and
# leave-one-trial-out, at 50 / 80 / 90 / 95 %, with the mean 90 % set size,
# the gain over a uniform guess and MAP within one grid step.
#
#   bash tools/spread_floor_sweep.sh STUDY_DB OUT_TSV [FLOOR ...]
#
# STUDY_DB is a solver study's database (tools/solver_study.sh); FLOORs
# default to 0 0.25 0.35 0.5 1 2. Extra `irlgrid holdout` flags (e.g.
# `--observables relative_timing`) go in HOLDOUT_ARGS. Rows are appended to
# OUT_TSV as each floor finishes.
set -euo pipefail
cd "$(dirname "$0")/.."
DB=${1:?usage: spread_floor_sweep.sh STUDY_DB OUT_TSV [FLOOR ...]}
OUT=${2:?usage: spread_floor_sweep.sh STUDY_DB OUT_TSV [FLOOR ...]}
shift 2
FLOORS=("$@")
[ ${#FLOORS[@]} -gt 0 ] || FLOORS=(0 0.25 0.35 0.5 1 2)
BIN=${BIN:-target/release/irlgrid}
[ -x "$BIN" ] || cargo build --release --bin irlgrid
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 tools/lib/search_outputs.py "$DB" > "$tmp/outputs.json"
printf 'floor\theld_out\tcases\tcov50\tcov80\tcov90\tcov95\tsize90\tgain_nats\twithin_one\n' > "$OUT"
for f in "${FLOORS[@]}"; do
  # shellcheck disable=SC2086
  "$BIN" holdout --outputs "$tmp/outputs.json" --solver-spread-floor "$f" ${HOLDOUT_ARGS:-} \
    --out "$tmp/h.json" > /dev/null
  python3 - "$tmp/h.json" "$f" >> "$OUT" <<'PY'
import json, sys
h, floor = json.load(open(sys.argv[1])), sys.argv[2]
def row(name, cov, within):
    lv = {round(l["level"] * 100): l for l in cov["levels"]}
    print("\t".join([floor, name, str(cov["cases"])]
                    + [f"{lv[p]['coverage']:.3f}" for p in (50, 80, 90, 95)]
                    + [f"{lv[90]['mean_set_size']:.2f}", f"{cov['gain_nats']:.3f}", within]))
for b in h["by_solver"]:
    row(b["solver"], b["coverage"]["posterior"], f"{b['within_one']['posterior']}/{b['cases']}"
        if isinstance(b.get("within_one"), dict) else "")
if h.get("by_solver_overall"):
    row("all", h["by_solver_overall"]["posterior"], "")
t = h["methods"]["posterior"]
row("leave-one-trial-out", h["coverage"]["posterior"], f"{t['within_one']}/{h['cases']}")
PY
  grep -P "^$f\t" "$OUT"
done
