#!/usr/bin/env bash
# Measures a reward preset (docs/reward-study.md): trains TRIALS policies per
# w1 of the preset's grid, tables convergence, stand-up duration, torque usage
# and path area per w1 (raw, one line per run, written as runs finish), runs
# leave-one-trial-out recovery (`irlgrid holdout`), and solves the learner-free
# optimum per w1 (`irlgrid optimize`) for PPO's optimality gap.
#
#   PRESET=power TRIALS=8 bash tools/reward_study.sh          # ~25 min on 2 idle cores
#   PRESET=paper GRID=0.1,1,16 TRIALS=2 bash tools/reward_study.sh   # a screen
#   SET="effort_exponent=2 height_offset=1" GRID=0.1,1,10 OUT=target/rs/x \
#     bash tools/reward_study.sh      # a form that is not a preset (yet):
#                                     # reward fields set on top of PRESET
#
# Outputs under OUT (default target/reward-study/$PRESET): runs/, runs.tsv,
# analysis.json, holdout.json, optimum.json, summary.tsv. Re-running skips finished runs.
set -euo pipefail
cd "$(dirname "$0")/.."
source tools/lib/train_grid.sh
PRESET=${PRESET:-paper}
BIN=${BIN:-target/release/irlgrid}
[ -x "$BIN" ] || cargo build --release --bin irlgrid
GRID=${GRID:-$("$BIN" presets | python3 -c "import json,sys; print(','.join(str(v) for p in json.load(sys.stdin) if p['name']=='$PRESET' for v in p['w1_grid']))")}
[ -n "$GRID" ] || { echo "unknown preset $PRESET" >&2; exit 2; }
TRIALS=${TRIALS:-8}
STEPS=${STEPS:-1500000}
JOBS=${JOBS:-$(nproc)}
OUT=${OUT:-target/reward-study/$PRESET}
mkdir -p "$OUT/runs"
# SET: reward fields on top of the preset, for training (a config file) and
# for the optimizer (--set), so that both solve the same task.
SET=${SET:-}
EXTRA="--preset $PRESET"
OPT_SET=()
if [ -n "$SET" ]; then
  python3 -c "
import json, sys
r = {}
for kv in sys.argv[1:]:
    k, v = kv.split('=', 1)
    try: r[k] = float(v)
    except ValueError: r[k] = v
print(json.dumps({'env': {'reward': r}}))" $SET > "$OUT/form.json"
  EXTRA="$EXTRA --config $OUT/form.json"
  for kv in $SET; do OPT_SET+=(--set "$kv"); done
fi

echo "==> $PRESET ${SET:+($SET) }: w1 = $GRID x $TRIALS trials, $STEPS steps, $JOBS at a time"
train_grid "$BIN" "$GRID" "$TRIALS" "$STEPS" "$JOBS" "$OUT" "$EXTRA"

echo "==> optimum per w1 (continuation from the lowest)"
[ -f "$OUT/optimum.json" ] || [ "${SKIP_OPT:-0}" = 1 ] ||
  "$BIN" optimize --preset "$PRESET" "${OPT_SET[@]}" --w1 "$GRID" --out "$OUT/optimum.json"

echo "==> per-w1 path area of PPO's trials (irlgrid analyze)"
"$BIN" analyze --runs "$OUT"/runs/* --out "$OUT/analysis.json" > /dev/null

echo "==> leave-one-trial-out recovery"
"$BIN" holdout --runs "$OUT/runs" --out "$OUT/holdout.json" > "$OUT/holdout.txt"
cat "$OUT/holdout.txt"

python3 tools/reward_table.py "$OUT" | tee "$OUT/summary.tsv"
