#!/usr/bin/env bash
# Cross-solver calibration (docs/inference.md#leave-one-solver-out): one
# search on this machine whose grid runs every (w1, trial) as several
# solver variants, then the leave-one-solver-out table of its
# identifiability report.
#
#   bash tools/solver_study.sh [OUT_DIR]
#
# Environment (defaults in brackets): PRESET [paper], GRID
# [0.1,0.5,1,2,4,8,16], TRIALS [8], BUDGET [1500000] for the `ppo`
# variant, SHORT [1000000] for `ppo-1m`, OPT_ITERS [250] and OPT_RESTARTS
# [4] for `optimizer`, SEED [1001], WORKERS [cores]. Writes OUT_DIR/request.json,
# the result document OUT_DIR/result.json, its CSV rows of the solver
# tables (OUT_DIR/solvers.tsv, OUT_DIR/lovo.tsv) and the run's log; the
# database OUT_DIR/study.db keeps every finished job, so a stopped study
# resumes only by starting again (the search is submitted anew).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-target/solver-study}
PRESET=${PRESET:-paper}
GRID=${GRID:-0.1,0.5,1,2,4,8,16}
TRIALS=${TRIALS:-8}
BUDGET=${BUDGET:-1500000}
SHORT=${SHORT:-1000000}
OPT_ITERS=${OPT_ITERS:-250}
OPT_RESTARTS=${OPT_RESTARTS:-4}
SEED=${SEED:-1001}
BIN=${BIN:-target/release/irlgrid}
[ -x "$BIN" ] || cargo build --release --bin irlgrid
mkdir -p "$OUT"
cat > "$OUT/request.json" <<JSON
{
  "name": "solver study: $PRESET, $TRIALS trials",
  "reward_preset": "$PRESET",
  "reward_grid": {"w1": [$GRID]},
  "trials": $TRIALS,
  "seed": $SEED,
  "training": {"env_steps": $BUDGET},
  "solvers": [
    {"name": "ppo", "kind": "ppo"},
    {"name": "ppo-1m", "kind": "ppo", "training": {"env_steps": $SHORT}},
    {"name": "optimizer", "kind": "optimizer",
     "optimizer": {"iterations": $OPT_ITERS, "restarts": $OPT_RESTARTS}}
  ]
}
JSON
rm -f "$OUT/study.db" "$OUT/study.db-wal" "$OUT/study.db-shm"
"$BIN" run "$OUT/request.json" --exit --bind 127.0.0.1:0 --db "$OUT/study.db" \
  ${WORKERS:+--workers "$WORKERS"} --out "$OUT/result.json" 2>"$OUT/run.log" | tee "$OUT/summary.txt"
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
doc = json.load(open(f"{out}/result.json"))
with open(f"{out}/solvers.tsv", "w") as f:
    f.write("w1\tsolver\tkind\ttrials_used\tbest_return_mean\tgap_pct\tduration_mean\tarea_mean\n")
    for w in doc["weights"]:
        for s in w["solvers"]:
            row = [w["value"], s["solver"]["name"], s["solver"]["kind"], s["trials_used"],
                   s["best_return_mean"], s["gap_pct"], s["duration_mean"], s["area_mean"]]
            f.write("\t".join("" if v is None else str(v) for v in row) + "\n")
h = doc["identifiability"]
with open(f"{out}/lovo.tsv", "w") as f:
    f.write("held_out\tmethod\tcases\tcov50\tcov80\tcov90\tcov95\tsize90\tgain_nats\n")
    rows = [(b["solver"], b["coverage"]) for b in h.get("by_solver", [])]
    rows.append(("all", h.get("by_solver_overall", {})))
    rows.append(("leave-one-trial-out", h["coverage"]))
    for name, cov in rows:
        for m in ("posterior", "posterior_one_solver"):
            c = cov.get(m)
            if not c:
                continue
            lv = {round(l["level"] * 100): l for l in c["levels"]}
            f.write("\t".join([name, m, str(c["cases"])]
                              + [f"{lv[p]['coverage']:.3f}" for p in (50, 80, 90, 95)]
                              + [f"{lv[90]['mean_set_size']:.2f}", f"{c['gain_nats']:.3f}"]) + "\n")
print(open(f"{out}/lovo.tsv").read())
PY
