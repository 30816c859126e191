#!/usr/bin/env bash
# A coordinator SIGKILLed between accepting an output and storing its
# trial summary loses nothing: the coordinator runs with
# IRLGRID_FAULT=between-result-and-summary, which kills it (SIGKILL) inside
# the accepting transaction, after the output's row is written and before
# its summary is. Then: the job is still leased, neither row is in the
# database; the restarted coordinator accepts the same upload under the
# same lease, and the job has exactly one result and one summary, and
# the result document counts it. Needs the release binary (IRLGRID_BIN).
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/reliability/common.sh

with_work_dir
need_release_binary
port=$(free_port)
db=$work/crash.db
url=http://127.0.0.1:$port

IRLGRID_FAULT=between-result-and-summary start_coordinator "$port" "$db" "$work/c1.log"
python3 - "$url" "$work/lease.json" <<'PY'
import json, sys, urllib.request
url, out = sys.argv[1], sys.argv[2]
def post(path, body):
    r = urllib.request.Request(url + path, json.dumps(body).encode(),
                               {"content-type": "application/json"})
    return json.load(urllib.request.urlopen(r, timeout=10))
sid = post("/api/v1/searches", {"name": "crash", "reward_grid": {"w1": [1.0]}, "trials": 1,
    "training": {"env_steps": 1000},
    "sampling": {"successful_episodes": 1, "top_k": 1, "max_attempts": 10, "n_envs": 1}})["id"]
lease = post("/api/v1/leases", {"worker": "w"})
n = 70
ep = {"com_t": [0.35 * k / (n - 1) for k in range(n)],
      "com_x": [0.1 * __import__("math").sin(3.141592653589793 * k / (n - 1)) for k in range(n)],
      "com_z": [0.6 + 0.38 * k / (n - 1) for k in range(n)],
      "return": 930.0, "torque_usage": 90.0, "steps": 7}
upload = {"lease_token": lease["lease_token"], "output": {"final_success_rate": 0.9,
    "env_steps": 1000, "successes_found": 1, "successes_wanted": 1, "sampling_attempts": 2,
    "episodes": [ep]}}
json.dump({"sid": sid, "job": lease["job_id"], "upload": upload}, open(out, "w"))
try:
    urllib.request.urlopen(urllib.request.Request(url + f"/api/v1/jobs/{lease['job_id']}/result",
        json.dumps(upload).encode(), {"content-type": "application/json"}), timeout=10)
    print("crash: the upload was answered; the fault point did not kill the coordinator")
    sys.exit(1)
except Exception as e:
    print(f"upload cut off as expected: {e.__class__.__name__}")
PY
status=0
wait "$COORD_PID" 2>/dev/null || status=$?
COORD_PID=
if [ "$status" -ne 137 ]; then
  echo "crash: the coordinator exited with $status, not SIGKILL (137)" >&2
  cat "$work/c1.log" >&2
  exit 1
fi
grep -q "fault point reached" "$work/c1.log"

python3 - "$db" "$work/lease.json" before <<'PY'
import json, sqlite3, sys
db, lease, when = sys.argv[1], json.load(open(sys.argv[2])), sys.argv[3]
c = sqlite3.connect(db)
job = lease["job"]
status = c.execute("select status from jobs where id = ?", (job,)).fetchone()[0]
results = c.execute("select count(*) from job_results where job_id = ?", (job,)).fetchone()[0]
summaries = c.execute("select count(*) from trial_summaries where job_id = ?", (job,)).fetchone()[0]
assert c.execute("pragma integrity_check").fetchone()[0] == "ok"
print(f"after the kill: job {status}, {results} result rows, {summaries} summary rows")
assert (status, results, summaries) == ("leased", 0, 0), "a half-written acceptance survived"
PY

start_coordinator "$port" "$db" "$work/c2.log"
python3 - "$url" "$db" "$work/lease.json" <<'PY'
import json, sqlite3, sys, time, urllib.request
url, db, lease = sys.argv[1], sys.argv[2], json.load(open(sys.argv[3]))
job = lease["job"]
r = urllib.request.Request(url + f"/api/v1/jobs/{job}/result",
    json.dumps(lease["upload"]).encode(), {"content-type": "application/json"})
ack = json.load(urllib.request.urlopen(r, timeout=10))
assert ack["converged"] is True, ack
for _ in range(100):
    doc = json.load(urllib.request.urlopen(url + f"/api/v1/searches/{lease['sid']}/results"))
    if not doc["partial"]:
        break
    time.sleep(0.1)
assert doc["weights"][0]["trials_used"] == 1, doc["weights"][0]
c = sqlite3.connect(db)
rows = c.execute("""select j.status, (select count(*) from job_results r where r.job_id = j.id),
    (select count(*) from trial_summaries s where s.job_id = j.id) from jobs j where j.id = ?""",
    (job,)).fetchone()
print(f"after the restart and the same upload: job {rows[0]}, {rows[1]} result, {rows[2]} summary")
assert rows == ("done", 1, 1), rows
PY
stop_coordinator
echo "summary_crash: ok"
