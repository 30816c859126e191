#!/usr/bin/env bash
# Recovery check on synthetic subjects: plant w1 values, generate
# subjects from policies trained at those values, run the grid search locally
# (`irlgrid train` per grid point and trial, then `irlgrid analyze`) and check
# that the w1 inferred by area difference is the planted grid value or its
# grid neighbour for every subject. Prints the recovery table.
#
#   bash tools/recovery.sh            # defaults below, ~10 min on 2 idle cores
#   GRID=0.1,0.5,1,2,4,8,16 PLANTED=0.5,2,8 TRIALS=10 STEPS=4000000 bash tools/recovery.sh
#
# The grid policies use seeds disjoint from the subjects' policies, so a
# subject is never scored against the very policy that produced it.
#
# It then runs `irlgrid holdout` on the same grid: every grid trial in turn
# scored as a subject against the grid without it, GRID x TRIALS cases in
# all, which measures recovery with far more cases than the few subjects.
set -euo pipefail
cd "$(dirname "$0")/.."
source tools/lib/train_grid.sh

GRID=${GRID:-0.1,0.5,1,2,4,8,16}
PLANTED=${PLANTED:-0.5,2,8}
TRIALS=${TRIALS:-3}
STEPS=${STEPS:-4000000}
PER_WEIGHT=${PER_WEIGHT:-2}
NOISE_M=${NOISE_M:-0.002}
BODY=${BODY:-0.05}
JOBS=${JOBS:-$(nproc)}
OUT=${OUT:-target/recovery}
BIN=${BIN:-target/release/irlgrid}

if [ ! -x "$BIN" ]; then
  cargo build --release --bin irlgrid
fi
mkdir -p "$OUT/runs"

echo "==> synthetic subjects at w1 = $PLANTED ($PER_WEIGHT each)"
"$BIN" synth-subjects --w1 "$PLANTED" --seed 77 --per-weight "$PER_WEIGHT" \
  --steps "$STEPS" --policies "$OUT/subject-policies" \
  --body-perturbation "$BODY" --noise-m "$NOISE_M" --out "$OUT/subjects.csv"

echo "==> grid w1 = $GRID x $TRIALS trials, $STEPS env steps each, $JOBS at a time"
train_grid "$BIN" "$GRID" "$TRIALS" "$STEPS" "$JOBS" "$OUT"

echo "==> leave-one-trial-out recovery over the grid"
"$BIN" holdout --runs "$OUT/runs" --out "$OUT/holdout.json"

echo "==> analyze"
"$BIN" analyze --runs "$OUT/runs" --subjects "$OUT/subjects.csv" --out "$OUT/result.json"

python3 - "$OUT/result.json" "$OUT/subjects.json" "$GRID" <<'EOF'
import json, sys
doc = json.load(open(sys.argv[1]))
planted = {s["subject"]: s["planted_w1"] for s in json.load(open(sys.argv[2]))["subjects"]}
grid = [float(g) for g in sys.argv[3].split(",")]
def idx(w):
    return min(range(len(grid)), key=lambda i: abs(grid[i] - w))
print("\nweights: w1, trials converged/done, area mean +- SEM, torque mean +- SEM")
for w in doc["weights"]:
    p = w["params"]["w1"]
    f = lambda k, d: "-" if w.get(k) is None else f"{w[k]:.{d}f}"
    print(f"  {p:>5}  {w['trials_converged']}/{w['trials_done']}  "
          f"{f('area_mean', 4)} +- {f('area_sem', 4)}  "
          f"{f('torque_usage_mean', 1)} +- {f('torque_usage_sem', 1)}")
print(f"\n{'subject':<26} {'planted':>8} {'area':>8} {'corr':>8}  area ok")
bad = 0
for s in doc["subjects"]:
    p = planted[s["subject"]]
    ia, ic = s["methods"]["area"]["inferred"], s["methods"]["correlation"]["inferred"]
    ok = ia is not None and abs(idx(ia) - idx(p)) <= 1
    bad += not ok
    print(f"{s['subject']:<26} {p:>8} {ia!s:>8} {ic!s:>8}  {'yes' if ok else 'NO'}")
n = len(doc["subjects"])
print(f"\nrecovered (planted value or grid neighbour, by area): {n - bad}/{n}")
sys.exit(1 if bad else 0)
EOF
