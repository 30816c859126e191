#!/usr/bin/env bash
# End-to-end check of deploy/: builds the image, brings up a coordinator and
# 3 workers with deploy/compose.yaml, and through the REST API (curl):
#   1. runs a tiny search (w1 in {0.5, 2} x 2 trials) and checks its result
#      document; the workers hold only the worker token, which can lease
#      but cannot submit or read (tests/worker_token_check.py);
#   2. kills a worker container holding a job in the middle of a second
#      search and checks that the search still completes with every job done
#      exactly once (its lease expires and another worker redoes it);
#   3. restarts the coordinator and checks that the searches survived in the
#      volume and that the remaining workers reconnect and finish a third.
# Everything is torn down (`down -v`) on any exit.
#
#   bash tests/compose/smoke.sh
#
# Environment:
#   SMOKE_SKIP_BUILD=1   use the existing $IRLGRID_IMAGE instead of building
#   IRLGRID_IMAGE        image tag (default irlgrid:smoke)
#   COMPOSE              compose command (default: `docker compose` if the
#                        plugin answers, else `docker-compose`)
#   SMOKE_TIMEOUT        seconds for everything after the build (default 600)
#   SMOKE_ENV_STEPS      training steps per job of search 2 (default 524288;
#                        long enough for a job to be mid-flight when killed)
set -euo pipefail
cd "$(dirname "$0")/../.."

log() { printf '[smoke %s] %s\n' "$(date +%T)" "$*"; }
fail() {
  printf '[smoke %s] FAIL: %s\n' "$(date +%T)" "$*" >&2
  exit 1
}

command -v curl >/dev/null || fail "curl is needed"
command -v python3 >/dev/null || fail "python3 is needed (JSON checks)"
docker info >/dev/null 2>&1 || fail "no Docker engine answers (docker info)"

if [ -n "${COMPOSE:-}" ]; then
  read -r -a compose_cmd <<<"$COMPOSE"
elif docker compose version >/dev/null 2>&1; then
  compose_cmd=(docker compose)
elif command -v docker-compose >/dev/null; then
  compose_cmd=(docker-compose)
else
  fail "neither \`docker compose\` nor \`docker-compose\` is installed"
fi

export IRLGRID_IMAGE=${IRLGRID_IMAGE:-irlgrid:smoke}
if [ "${SMOKE_SKIP_BUILD:-0}" = 1 ]; then
  log "using the existing image $IRLGRID_IMAGE (SMOKE_SKIP_BUILD=1)"
  docker image inspect "$IRLGRID_IMAGE" >/dev/null 2>&1 || fail "no image $IRLGRID_IMAGE"
else
  log "building $IRLGRID_IMAGE with deploy/build.sh"
  bash deploy/build.sh "$IRLGRID_IMAGE"
fi

deadline=$((SECONDS + ${SMOKE_TIMEOUT:-600}))
project=irlgrid-smoke-$$-$RANDOM
workdir=$(mktemp -d)

# Settings for this run only: an empty env file keeps a developer's
# deploy/.env out of it, and exported variables win over it anyway.
: >"$workdir/empty.env"
export IRLGRID_TOKEN=smoke-$RANDOM$RANDOM$RANDOM
# The token reaches the containers as a secret file (mktemp -d is mode 700;
# the file must be readable by the image's user, see compose.yaml).
printf '%s\n' "$IRLGRID_TOKEN" >"$workdir/irlgrid_token"
chmod 644 "$workdir/irlgrid_token"
export IRLGRID_TOKEN_SECRET="$workdir/irlgrid_token"
# The workers get only the worker token.
IRLGRID_WORKER_TOKEN=smoke-worker-$RANDOM$RANDOM$RANDOM
printf '%s\n' "$IRLGRID_WORKER_TOKEN" >"$workdir/irlgrid_worker_token"
chmod 644 "$workdir/irlgrid_worker_token"
export IRLGRID_WORKER_TOKEN_SECRET="$workdir/irlgrid_worker_token"
export IRLGRID_PUBLISH_ADDR=127.0.0.1
export IRLGRID_PORT=0 # any free port; asked with `compose port` below
export IRLGRID_LEASE_SECONDS=10
export IRLGRID_COORDINATOR=http://coordinator:8080
export IRLGRID_WORKER_JOBS=1
export IRLGRID_WORKER_CPUS=1
export IRLGRID_WORKER_MEM=1g
export IRLGRID_COORDINATOR_CPUS=1
export IRLGRID_COORDINATOR_MEM=1g
export IRLGRID_LOG=info
export IRLGRID_LOG_JSON=

compose() {
  "${compose_cmd[@]}" --env-file "$workdir/empty.env" -f deploy/compose.yaml -p "$project" "$@"
}

teardown() {
  local rc=$?
  trap - EXIT INT TERM
  if [ "$rc" -ne 0 ]; then
    log "failed (exit $rc): containers and last log lines follow"
    compose ps -a || true
    compose logs --no-color --tail 60 || true
    for c in $(compose ps -q coordinator 2>/dev/null); do
      log "coordinator health probes:"
      docker inspect -f '{{range .State.Health.Log}}exit {{.ExitCode}}: {{.Output}}{{end}}' "$c" | tail -n 8 || true
    done
  fi
  log "tearing down project $project"
  compose down -v --remove-orphans -t 5 >/dev/null 2>&1 ||
    compose down -v --remove-orphans -t 5 || true
  rm -rf "$workdir"
  if [ "$rc" -eq 0 ]; then log "PASSED"; else log "FAILED"; fi
  exit "$rc"
}
trap teardown EXIT
trap 'exit 130' INT TERM

remaining() {
  local left=$((deadline - SECONDS))
  [ "$left" -gt 0 ] || fail "time budget (SMOKE_TIMEOUT=${SMOKE_TIMEOUT:-600}s) used up"
  echo "$left"
}

# JSON field extraction: json FILE EXPR, EXPR a Python expression over `d`.
json() { python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))' "$1" "$2"; }

base=""
refresh_base() {
  local hp
  hp=$(compose port coordinator 8080 | tail -n1)
  [ -n "$hp" ] || fail "the coordinator publishes no port"
  base="http://127.0.0.1:${hp##*:}"
}

# api METHOD PATH [BODY]: the body goes to $workdir/out, the status to stdout.
api() {
  local args=(-sS --max-time 15 -o "$workdir/out" -w '%{http_code}' -X "$1"
    -H "Authorization: Bearer $IRLGRID_TOKEN")
  [ $# -ge 3 ] && args+=(-H 'Content-Type: application/json' --data-binary "$3")
  curl "${args[@]}" "$base$2" || echo 000
}

wait_healthy() {
  local left
  left=$(remaining)
  for _ in $(seq "$left"); do
    if [ "$(curl -s -o /dev/null -w '%{http_code}' --max-time 3 "$base/healthz")" = 200 ]; then
      return 0
    fi
    sleep 1
    remaining >/dev/null
  done
  fail "coordinator not healthy at $base/healthz"
}

worker_containers() { compose ps -q worker | sort; }

# submit NAME TRIALS ENV_STEPS W1... -> prints the search id
submit() {
  local name=$1 trials=$2 steps=$3
  shift 3
  local grid
  grid=$(
    IFS=,
    echo "$*"
  )
  local body
  body=$(
    cat <<JSON
{"name": "$name", "reward_grid": {"w1": [$grid]}, "trials": $trials, "seed": 7,
 "max_attempts": 3,
 "training": {"env_steps": $steps, "n_envs": 8, "n_steps": 128, "minibatch_size": 256, "epochs": 2},
 "sampling": {"successful_episodes": 5, "top_k": 5, "max_attempts": 40, "n_envs": 8}}
JSON
  )
  local code
  code=$(api POST /api/v1/searches "$body")
  [ "$code" = 201 ] || fail "POST /api/v1/searches answered $code: $(cat "$workdir/out")"
  json "$workdir/out" 'd["id"]'
}

# status SEARCH -> writes $workdir/status.json, prints the search state
status() {
  local code
  code=$(api GET "/api/v1/searches/$1")
  [ "$code" = 200 ] || fail "GET /api/v1/searches/$1 answered $code: $(cat "$workdir/out")"
  cp "$workdir/out" "$workdir/status.json"
  json "$workdir/status.json" 'd["status"]'
}

# wait_done SEARCH: polls until completed, printing job counts as they change.
wait_done() {
  local id=$1 st last="" now
  while :; do
    remaining >/dev/null
    st=$(status "$id")
    now=$(json "$workdir/status.json" '"{status}: queued {queued} leased {leased} done {done} failed {failed} of {total}".format(status=d["status"], **d["jobs"])')
    [ "$now" = "$last" ] || log "  search ${id:0:8} $now"
    last=$now
    case $st in
      completed) return 0 ;;
      cancelled) fail "search $id was cancelled" ;;
    esac
    sleep 2
  done
}

# check_jobs SEARCH POINTS TRIALS: every (point, trial) job exists once and is
# done, none failed; the results document has POINTS weights with TRIALS done
# trials each.
check_jobs() {
  local id=$1 points=$2 trials=$3 code
  code=$(api GET "/api/v1/searches/$id/jobs")
  [ "$code" = 200 ] || fail "GET .../jobs answered $code"
  cp "$workdir/out" "$workdir/jobs.json"
  code=$(api GET "/api/v1/searches/$id/results")
  [ "$code" = 200 ] || fail "GET .../results answered $code"
  cp "$workdir/out" "$workdir/results.json"
  python3 - "$workdir/status.json" "$workdir/jobs.json" "$workdir/results.json" "$points" "$trials" <<'PY' ||
import json, sys
status, jobs, results = (json.load(open(p)) for p in sys.argv[1:4])
points, trials = int(sys.argv[4]), int(sys.argv[5])
want = points * trials
errors = []
c = status["jobs"]
if status["status"] != "completed":
    errors.append(f"search status {status['status']}")
if (c["total"], c["done"], c["failed"], c["queued"], c["leased"]) != (want, want, 0, 0, 0):
    errors.append(f"job counts {c}, want {want} done of {want}")
if len(jobs) != want:
    errors.append(f"{len(jobs)} jobs listed, want {want}")
keys = [(j["point_idx"], j["trial"]) for j in jobs]
if len(set(keys)) != len(keys):
    errors.append(f"duplicate (point, trial) jobs: {sorted(keys)}")
if set(keys) != {(p, t) for p in range(points) for t in range(trials)}:
    errors.append(f"(point, trial) pairs {sorted(keys)}")
for j in jobs:
    if j["status"] != "done":
        errors.append(f"job {j['id']} is {j['status']} (last error {j.get('last_error')})")
if results.get("partial"):
    errors.append("results document still partial")
weights = results.get("weights", [])
if len(weights) != points:
    errors.append(f"{len(weights)} weights in the results document, want {points}")
for w in weights:
    if w.get("trials_done") != trials:
        errors.append(f"weight {w.get('params')}: trials_done {w.get('trials_done')}, want {trials}")
    # Each trial's output is counted once in the document.
    got = sorted(t["trial"] for t in w.get("trials", []))
    if got != list(range(trials)):
        errors.append(f"weight {w.get('params')}: trials {got} in the document, want 0..{trials - 1} once each")
if errors:
    print("\n".join(errors), file=sys.stderr)
    sys.exit(1)
relet = [j for j in jobs if j.get("lease_count", 1) > 1]
print(f"{want} jobs, each done once; {len(relet)} re-leased after a lost lease; "
      f"weights " + ", ".join(f"w1={w['params'].get('w1')}: {w['trials_done']} trials" for w in weights))
PY
    fail "search $id: checks above failed"
}

# --- the image -------------------------------------------------------------
user=$(docker image inspect -f '{{.Config.User}}' "$IRLGRID_IMAGE")
case $user in
  "" | 0 | 0:* | root | root:*) fail "image runs as root (USER '$user')" ;;
esac
log "image $IRLGRID_IMAGE runs as user $user"

# --- bring-up --------------------------------------------------------------
log "compose: ${compose_cmd[*]} ($("${compose_cmd[@]}" version --short 2>/dev/null || echo '?')), project $project"
timeout "$(remaining)" "${compose_cmd[@]}" --env-file "$workdir/empty.env" \
  -f deploy/compose.yaml -p "$project" up -d --scale worker=3 ||
  fail "compose up failed"
refresh_base
wait_healthy
log "coordinator healthy at $base"
[ "$(worker_containers | wc -l)" -eq 3 ] || fail "want 3 worker containers: $(compose ps)"

code=$(curl -sS -o /dev/null -w '%{http_code}' --max-time 10 -X POST \
  -H 'Content-Type: application/json' -d '{"reward_grid":{"w1":[1]},"trials":1}' \
  "$base/api/v1/searches")
[ "$code" = 401 ] || fail "a submission without the token answered $code, want 401"
log "a submission without the token is refused (401)"

# --- 1. a tiny search ------------------------------------------------------
log "search 1: w1 in {0.5, 2} x 2 trials, 4096 training steps per job"
s1=$(submit smoke-1 2 4096 0.5 2)
wait_done "$s1"
summary=$(check_jobs "$s1" 2 2)
log "  $summary"
code=$(curl -sS -o /dev/null -w '%{http_code}' --max-time 10 "$base/api/v1/searches/$s1/results")
[ "$code" = 401 ] || fail "the results without the token answered $code, want 401"
log "the results without the token are refused (401)"
python3 tests/worker_token_check.py "$base" "$IRLGRID_WORKER_TOKEN" "$s1" | sed 's/^/  /'
[ "${PIPESTATUS[0]}" = 0 ] || fail "the worker token did more or less than a worker's calls"

# --- 2. a worker killed mid-search -----------------------------------------
steps2=${SMOKE_ENV_STEPS:-524288}
log "search 2: w1 in {0.5, 1, 2} x 2 trials, $steps2 steps per job; a worker will be killed"
s2=$(submit smoke-2 2 "$steps2" 0.5 1 2)
victim="" victim_job=""
# Leased jobs still in the first half of their training, as "id worker"
# lines: a worker killed then is sure to die before it uploads.
early_leased='"\n".join("%s %s" % (j["id"], j["worker"]) for j in d
  if j["status"] == "leased" and j["worker"] and j.get("phase") != "sampling"
  and (j.get("progress") or {}).get("env_steps", 0) * 2 < (j.get("progress") or {}).get("total_env_steps", 1))'
while [ -z "$victim" ]; do
  remaining >/dev/null
  code=$(api GET "/api/v1/searches/$s2/jobs")
  [ "$code" = 200 ] || fail "GET .../jobs answered $code"
  cp "$workdir/out" "$workdir/jobs.json"
  # Worker names start with their container's hostname (its short id).
  while read -r job owner; do
    [ -n "$owner" ] || continue
    for c in $(worker_containers); do
      h=$(docker inspect -f '{{.Config.Hostname}}' "$c")
      case $owner in "$h"*)
        victim=$c victim_job=$job
        break 2
        ;;
      esac
    done
  done < <(json "$workdir/jobs.json" "$early_leased")
  [ -n "$victim" ] || sleep 1
done
log "  killing worker ${victim:0:12} while it holds job $victim_job"
docker kill "$victim" >/dev/null
wait_done "$s2"
summary=$(check_jobs "$s2" 3 2)
log "  $summary"
leases=$(json "$workdir/jobs.json" "[j for j in d if j['id'] == $victim_job][0]['lease_count']")
[ "$leases" -ge 2 ] ||
  fail "job $victim_job of the killed worker was leased $leases time(s): it finished before the kill (raise SMOKE_ENV_STEPS)"
log "  job $victim_job of the killed worker was re-leased ($leases leases) and done once"

# --- 3. coordinator restart: state kept, workers reconnect ----------------
log "restarting the coordinator"
compose restart -t 10 coordinator >/dev/null
refresh_base
wait_healthy
st=$(status "$s1")
[ "$st" = completed ] || fail "after the restart search 1 is '$st'"
log "  searches kept across the restart (search 1 $st)"
s3=$(submit smoke-3 1 4096 1)
wait_done "$s3"
summary=$(check_jobs "$s3" 1 1)
log "  $summary"
log "  the surviving workers reconnected and finished search 3"
