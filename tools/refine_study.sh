#!/usr/bin/env bash
# Refinement from the paper grid toward subjects planted off the grid:
# synthetic subjects from policies trained at PLANTED w1 values (on the
# model's own body, with measurement noise), then one refining search over
# the paper grid run locally (`irlgrid run --exit`, a coordinator and
# in-process workers), rounds of added midpoints included. Writes the run's
# output, the refinement (JSON, every round's per-subject estimate) and a
# one-line summary per subject: estimate after the last round, its error
# against the planted value, and the jobs refinement added.
#
#   bash tools/refine_study.sh                      # defaults, ~20 min on 2 idle cores
#   PLANTED=5.7,11.3 TRIALS=5 ROUNDS=3 bash tools/refine_study.sh
set -euo pipefail
cd "$(dirname "$0")/.."

PLANTED=${PLANTED:-5.7,11.3}
GRID=${GRID:-0.1,0.5,1,2,4,8,16}
TRIALS=${TRIALS:-5}
ROUNDS=${ROUNDS:-3}
TARGET=${TARGET:-1.2}
PER_WEIGHT=${PER_WEIGHT:-2}
NOISE_M=${NOISE_M:-0.002}
BODY=${BODY:-0}
WORKERS=${WORKERS:-$(nproc)}
OUT=${OUT:-target/refine-study}
BIN=${BIN:-target/release/irlgrid}

if [ ! -x "$BIN" ]; then
  cargo build --release --bin irlgrid
fi
mkdir -p "$OUT"

echo "==> synthetic subjects at w1 = $PLANTED ($PER_WEIGHT each)"
"$BIN" synth-subjects --w1 "$PLANTED" --seed 77 --per-weight "$PER_WEIGHT" \
  --policies "$OUT/subject-policies" --body-perturbation "$BODY" \
  --noise-m "$NOISE_M" --out "$OUT/subjects.csv"

python3 - "$OUT" "$GRID" "$TRIALS" "$ROUNDS" "$TARGET" <<'PY'
import json, sys
out, grid, trials, rounds, target = sys.argv[1:]
req = {
    "name": f"refine study: paper grid toward planted subjects",
    "reward_grid": {"w1": [float(v) for v in grid.split(",")]},
    "trials": int(trials),
    "seed": 1,
    "subjects_csv": open(f"{out}/subjects.csv").read(),
    "refine": {"rounds": int(rounds), "target_ratio": float(target)},
}
json.dump(req, open(f"{out}/request.json", "w"), indent=1)
PY

echo "==> refining search: grid $GRID x $TRIALS trials, up to $ROUNDS rounds, target ratio $TARGET"
rm -f "$OUT/refine.db"*
start=$(date +%s)
"$BIN" run "$OUT/request.json" --exit --workers "$WORKERS" --db "$OUT/refine.db" \
  --bind 127.0.0.1:0 > "$OUT/run.txt"
echo "wall time: $(( $(date +%s) - start )) s" | tee -a "$OUT/run.txt"

# Read the stored refinement and jobs back through a coordinator on the
# study's database.
port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
"$BIN" coordinator --db "$OUT/refine.db" --bind "127.0.0.1:$port" > "$OUT/coordinator.log" 2>&1 &
coord=$!
trap 'kill $coord 2>/dev/null || true' EXIT
for _ in $(seq 100); do
  curl -sf "http://127.0.0.1:$port/healthz" >/dev/null && break
  sleep 0.1
done
id=$(curl -sf "http://127.0.0.1:$port/api/v1/searches" | python3 -c 'import json,sys; print(json.load(sys.stdin)[0]["id"])')
curl -sf "http://127.0.0.1:$port/api/v1/searches/$id/refinement" > "$OUT/refinement.json"
curl -sf "http://127.0.0.1:$port/api/v1/searches/$id/jobs" > "$OUT/jobs.json"

python3 - "$OUT" "$PLANTED" "$GRID" "$TRIALS" <<'PY' | tee "$OUT/summary.txt"
import json, sys
out, planted, grid, trials = sys.argv[1:]
r = json.load(open(f"{out}/refinement.json"))
jobs = json.load(open(f"{out}/jobs.json"))
side = json.load(open(f"{out}/subjects.json"))
truth = {s["subject"]: s["planted_w1"] for s in side["subjects"]}
grid_jobs = len(grid.split(",")) * int(trials)
added = [v for rd in r["rounds"] for v in rd["added"]]
rounds_used = sum(1 for rd in r["rounds"] if rd["added"])
print(f"rounds with added points: {rounds_used}; points added: {added}")
print(f"jobs: {len(jobs)} in all, {grid_jobs} for the grid, {len(jobs) - grid_jobs} added by refinement")
print(f"stop: {r['rounds'][-1]['stop']}")
print("subject | planted | estimate per round | final | error")
for s in r["rounds"][-1]["subjects"]:
    name = s["subject"]
    per_round = [next((x["estimate"] for x in rd["subjects"] if x["subject"] == name), None) for rd in r["rounds"]]
    est = s["estimate"]
    err = (est / truth[name] - 1) * 100 if est else float("nan")
    print(f"{name} | {truth[name]} | {' -> '.join(str(v) for v in per_round)} | {est} | {err:+.1f} %")
PY
