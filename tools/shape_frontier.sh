#!/usr/bin/env bash
# What does the path's shape cost under a reward, with no learner involved?
# For each w1, the optimizer (`irlgrid optimize`) finds the best movement
# without a constraint and then the best movement whose path area (the
# paper's, of the preprocessed path) is held at each TARGET by a penalty.
# The return lost against the free optimum is the price of that shape
# (docs/reward-study.md, Step 8). A reward identifies w1 by shape only if
# shapes other than its optimum's cost clearly more than PPO's own gap.
#
#   PRESET=paper W1=0.1,1,4,16 bash tools/shape_frontier.sh
#   PRESET=power W1=0.01,0.1,0.464,1 bash tools/shape_frontier.sh
#   TARGETS=-0.02,0,0.04,0.08 SET="success_step_cost=1" bash tools/shape_frontier.sh
#
# LADDER (a comma list): solve every answer by continuation up the LADDER
# values below its w1 first, as `irlgrid optimize --w1 a,b,...,w1` does. At
# high w1 a search that starts only from the w1 = 0 optimum can stall far
# below the true optimum (under `power` it does from w1 = 0.464 up), and
# the price of shape would then be measured from the wrong optimum.
#
# Writes OUT/w<w1>_<target>.json per answer and OUT/frontier.tsv (one line
# per answer, written as they finish). Re-running skips finished answers.
set -euo pipefail
cd "$(dirname "$0")/.."
PRESET=${PRESET:-paper}
W1=${W1:-0.1,1,4,16}
TARGETS=${TARGETS:--0.02,0,0.02,0.04,0.06,0.08,0.1}
BIN=${BIN:-target/release/irlgrid}
OUT=${OUT:-target/shape-frontier/$PRESET}
[ -x "$BIN" ] || cargo build --release --bin irlgrid
mkdir -p "$OUT"
LADDER=${LADDER:-}
SETS=()
for kv in ${SET:-}; do SETS+=(--set "$kv"); done

solve() { # w1 target-or-free
  local f="$OUT/w${1}_$2.json" ladder="$1" v
  [ -f "$f" ] && return
  for v in ${LADDER//,/ }; do
    awk -v v="$v" -v w="$1" 'BEGIN { exit !(v + 0 < w + 0) }' && ladder="$ladder,$v"
  done
  local constraint=()
  [ "$2" = free ] || constraint=(--area-target="$2")
  "$BIN" optimize --preset "$PRESET" "${SETS[@]}" --w1 "$ladder" "${constraint[@]}" --out "$f.all" > /dev/null
  # The answer for w1 itself, whether the file holds one answer or a ladder.
  python3 -c "
import json, sys
d = json.load(open('$f.all'))
d = d if isinstance(d, list) else [d]
json.dump(next(o for o in d if o['env']['reward']['w1'] == float('$1')), open('$f', 'w'))"
  rm "$f.all"
}

for w in ${W1//,/ }; do
  solve "$w" free
  for a in ${TARGETS//,/ }; do
    solve "$w" "$a"
  done
  echo "  done w1=$w" >&2
done

python3 - "$OUT" "$W1" "$TARGETS" <<'EOF' | tee "$OUT/frontier.tsv"
import json, pathlib, sys
out, w1s, targets = pathlib.Path(sys.argv[1]), sys.argv[2].split(","), sys.argv[3].split(",")
print("w1\ttarget\tarea\tsteps\treturn\treturn_lost\tlost_pct")
for w in w1s:
    free = json.loads((out / f"w{w}_free.json").read_text())
    f_ret = free["best"]["return"]
    for t in ["free"] + targets:
        o = json.loads((out / f"w{w}_{t}.json").read_text())
        b = o["best"]
        area = "-" if o["area"] is None else f"{o['area']:.4f}"
        lost = f_ret - b["return"]
        print(f"{w}\t{t}\t{area}\t{b['steps']}\t{b['return']:.2f}\t{lost:.2f}\t{100 * lost / abs(f_ret):.2f}")
EOF
