#!/usr/bin/env bash
# Scaling benchmark: the same grid finished by 1 worker process and
# by 2 worker processes (one job each), timed from the search's own started
# and finished timestamps. Run it on an otherwise idle machine: the target is
# a ratio of at most 0.55 on 2 cores.
#
#   bash tools/scaling.sh                 # 8 jobs of 400k env steps, 3 repeats
#   STEPS=1000000 REPEATS=1 bash tools/scaling.sh
set -euo pipefail
cd "$(dirname "$0")/.."

source tests/reliability/common.sh

STEPS=${STEPS:-400000}
REPEATS=${REPEATS:-3}
need_release_binary
BIN=$IRLGRID_BIN

with_work_dir
WORK=$work

cat >"$WORK/search.json" <<EOF
{"name": "scaling", "reward_grid": {"w1": [0.5, 1, 2, 4]}, "trials": 2, "seed": 5,
 "training": {"env_steps": $STEPS},
 "sampling": {"successful_episodes": 200, "top_k": 10, "max_attempts": 4000}}
EOF

# One timed search with $1 worker processes; prints its duration in seconds.
one_run() {
  local n=$1 port url
  port=$(free_port)
  url="http://127.0.0.1:$port"
  start_coordinator "$port" "$WORK/scaling-$n-$RANDOM.db" "$WORK/coord.log" >&2
  local id
  id=$("$BIN" submit "$WORK/search.json" --coordinator "$url")
  local ws=()
  for i in $(seq "$n"); do
    "$BIN" worker --coordinator "$url" --jobs 1 --name "w$i" --spool-dir "$WORK/spool-$n-$i" \
      >"$WORK/worker-$i.log" 2>&1 &
    ws+=("$!")
  done
  python3 - "$url" "$id" <<'EOF'
import json, sys, time, urllib.request
from datetime import datetime
url, sid = sys.argv[1], sys.argv[2]
while True:
    s = json.load(urllib.request.urlopen(f"{url}/api/v1/searches/{sid}"))
    if s["status"] != "running":
        break
    time.sleep(0.5)
if s["status"] != "completed" or s["jobs"]["done"] != s["jobs"]["total"]:
    sys.exit(f"search ended {s['status']} with jobs {s['jobs']}")
t = lambda k: datetime.fromisoformat(s[k].replace("Z", "+00:00")).timestamp()
print(f"{t('finished_at') - t('started_at'):.1f}")
EOF
  kill "${ws[@]}" 2>/dev/null || true
  wait "${ws[@]}" 2>/dev/null || true
  stop_coordinator
}

echo "grid: 4 w1 x 2 trials = 8 jobs, $STEPS env steps each; $REPEATS repeats"
one=()
two=()
for r in $(seq "$REPEATS"); do
  a=$(one_run 1)
  b=$(one_run 2)
  one+=("$a")
  two+=("$b")
  echo "repeat $r: 1 worker ${a}s, 2 workers ${b}s"
done
python3 - "${one[*]}" "${two[*]}" <<'EOF'
import statistics, sys
one = [float(x) for x in sys.argv[1].split()]
two = [float(x) for x in sys.argv[2].split()]
m1, m2 = statistics.median(one), statistics.median(two)
print(f"median: 1 worker {m1:.1f}s, 2 workers {m2:.1f}s, ratio {m2 / m1:.3f} (target <= 0.55)")
EOF
