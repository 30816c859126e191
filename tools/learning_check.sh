#!/usr/bin/env bash
# Learning check for the training code: every w1 of the paper grid, SEEDS
# seeds each, at the default budget (1.5 M steps, sampling of 1000
# successful episodes included). Writes one row per run to OUT/learning.tsv
# as runs finish, prints the table, and fails unless every run's final
# success is at least MIN (both the 1000-episode evaluation and the success
# fraction of the sampling rollouts, which is what the analysis calls a
# trial's final success). Also reports sampling time as a share of
# training time.
#
#   bash tools/learning_check.sh                 # 7 x 5 runs, ~6 min on 2 cores
#   GRID=0.1,16 SEEDS=2 bash tools/learning_check.sh
#
# Re-running skips finished runs.
set -euo pipefail
cd "$(dirname "$0")/.."

GRID=${GRID:-0.1,0.5,1,2,4,8,16}
SEEDS=${SEEDS:-5}
MIN=${MIN:-0.955}
JOBS=${JOBS:-$(nproc)}
OUT=${OUT:-target/learning-check}
BIN=${BIN:-target/release/irlgrid}

if [ ! -x "$BIN" ]; then
  cargo build --release --bin irlgrid
fi
mkdir -p "$OUT/runs"

for w in ${GRID//,/ }; do
  for s in $(seq 1 "$SEEDS"); do
    dir="$OUT/runs/w1_${w}_s$s"
    [ -f "$dir/summary.json" ] || echo "$w $s $dir"
  done
done | xargs -r -P "$JOBS" -n 3 sh -c \
  '"$0" train --w1 "$1" --seed "$2" --quiet --out "$3" >/dev/null && echo "  done w1=$1 seed $2"' "$BIN"

python3 - "$OUT" "$GRID" "$SEEDS" "$MIN" <<'PY'
import json, sys, pathlib
out, grid, seeds, floor = pathlib.Path(sys.argv[1]), sys.argv[2].split(","), int(sys.argv[3]), float(sys.argv[4])
rows, bad = [], []
for w in grid:
    for s in range(1, seeds + 1):
        d = json.load(open(out / "runs" / f"w1_{w}_s{s}" / "summary.json"))
        smp = d["sampling"]
        sample_success = smp["successes_found"] / max(smp["attempts"], 1)
        share = smp["wall_seconds"] / d["wall_seconds"]
        rows.append((w, s, d["final_success_rate"], sample_success, d["wall_seconds"],
                     d["steps_per_second"], smp["wall_seconds"], share))
        if min(d["final_success_rate"], sample_success) < floor:
            bad.append((w, s))
with open(out / "learning.tsv", "w") as f:
    f.write("w1\tseed\teval_success\tsampling_success\ttrain_s\tsteps_per_s\tsample_s\tsample_share\n")
    for r in rows:
        f.write("%s\t%d\t%.4f\t%.4f\t%.1f\t%.0f\t%.2f\t%.3f\n" % r)
print(open(out / "learning.tsv").read())
print("lowest eval success %.4f, lowest sampling success %.4f, largest sampling share %.1f %%, median steps/s %.0f"
      % (min(r[2] for r in rows), min(r[3] for r in rows), 100 * max(r[7] for r in rows),
         sorted(r[5] for r in rows)[len(rows) // 2]))
if bad:
    sys.exit("runs below %.3f: %s" % (floor, bad))
print("every run at or above %.3f" % floor)
PY
