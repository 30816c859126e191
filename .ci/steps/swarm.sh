#!/usr/bin/env bash
# CI step: deploy/compose.yaml as a Docker Swarm stack on a single-node swarm
# with the locally built image. Checks that
#   1. `docker stack deploy` brings the stack up (the admin and the worker
#      token as Docker secrets, the workers holding only the worker token)
#      and a tiny search completes, every job done exactly once; the worker
#      token can lease but cannot submit or read (tests/worker_token_check.py);
#   2. `docker service scale <stack>_worker=3` runs 3 workers, which share
#      a second search;
#   3. scaling back to 1 in the middle of it (Swarm stops 2 tasks with
#      SIGTERM, as Kubernetes does on pod deletion) hands their jobs back
#      without using an attempt, and the search still completes with every
#      job done exactly once.
# Where the kernel has no IPVS (no /proc/net/ip_vs, as on the CI machine),
# service virtual IPs and the routing mesh cannot work, and the stack is
# deployed with deploy/compose.no-ipvs.yaml added (DNS round robin, the
# coordinator's port published on its node).
# Then the stack, its volume and its secret are removed. The swarm is
# initialised only if the engine is in none, and then left again; an engine
# already in a single-node swarm is used as it is. Where Docker or a swarm
# is not available, it prints "SKIPPED: <reason>" and succeeds.
#
#   bash .ci/steps/swarm.sh
#
# Environment: IRLGRID_IMAGE (default: irlgrid:smoke when the compose step
# built it, else irlgrid:swarm built here with deploy/build.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT=$PWD

log() { printf '[swarm %s] %s\n' "$(date +%T)" "$*"; }
skip() {
  echo "SKIPPED: swarm stack ($*)"
  exit 0
}
fail() {
  echo "FAIL: $*" >&2
  exit 1
}

command -v docker >/dev/null 2>&1 || skip "no docker command"
timeout 20 docker info >/dev/null 2>&1 || skip "no Docker engine answers \`docker info\`"
command -v curl >/dev/null 2>&1 || skip "no curl"
command -v python3 >/dev/null 2>&1 || skip "no python3"
REL="python3 $ROOT/tests/reliability/rel.py"

state=$(docker info --format '{{.Swarm.LocalNodeState}}')
INITIALISED=0
case $state in
  inactive) ;;
  active)
    [ "$(docker info --format '{{.Swarm.ControlAvailable}}')" = true ] ||
      skip "this engine is a swarm worker, not a manager"
    nodes=$(docker node ls -q | wc -l)
    [ "$nodes" = 1 ] || skip "this engine is in a swarm of $nodes nodes; the local image is on this one only"
    ;;
  *) skip "swarm state '$state'" ;;
esac

# --- the image ---------------------------------------------------------------
if [ -n "${IRLGRID_IMAGE:-}" ]; then
  image=$IRLGRID_IMAGE
elif docker image inspect irlgrid:smoke >/dev/null 2>&1; then
  image=irlgrid:smoke
else
  image=irlgrid:swarm
fi
if ! docker image inspect "$image" >/dev/null 2>&1; then
  log "building $image with deploy/build.sh"
  bash deploy/build.sh "$image"
fi
log "image $image"

stack=irlgridci$$
work=$(mktemp -d)
# swarm init makes this network and leave keeps it: remove it if it is ours.
had_gwbridge=0
docker network inspect docker_gwbridge >/dev/null 2>&1 && had_gwbridge=1
cleanup() {
  local rc=$?
  trap - EXIT INT TERM
  if [ "$rc" -ne 0 ]; then
    docker stack ps --no-trunc "$stack" 2>/dev/null | head -n 20 || true
    for s in coordinator worker; do
      echo "--- ${stack}_$s (last lines)"
      docker service logs --no-trunc --tail 30 "${stack}_$s" 2>&1 || true
    done
  fi
  if docker stack ls --format '{{.Name}}' 2>/dev/null | grep -qx "$stack"; then
    docker stack rm "$stack" >/dev/null 2>&1 || true
    # The volume can go once the stack's containers are gone.
    for _ in $(seq 60); do
      [ -z "$(docker ps -aq --filter "label=com.docker.stack.namespace=$stack")" ] &&
        [ -z "$(docker network ls -q --filter "label=com.docker.stack.namespace=$stack")" ] && break
      sleep 1
    done
  fi
  docker volume rm "${stack}_irlgrid-data" >/dev/null 2>&1 || true
  if [ "$INITIALISED" = 1 ]; then
    docker swarm leave --force >/dev/null 2>&1 || true
    [ "$had_gwbridge" = 1 ] || docker network rm docker_gwbridge >/dev/null 2>&1 || true
    log "left the swarm this step made"
  fi
  rm -rf "$work"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

if [ "$state" = inactive ]; then
  out=$(docker swarm init --advertise-addr 127.0.0.1 2>&1) || skip "docker swarm init failed: $out"
  INITIALISED=1
  log "initialised a single-node swarm (left again at the end)"
else
  log "using the engine's existing single-node swarm"
fi

# --- stack up ----------------------------------------------------------------
files=(-c deploy/compose.yaml)
if [ ! -e /proc/net/ip_vs ]; then
  # Service VIPs and the routing mesh need IPVS; this kernel has none.
  files+=(-c deploy/compose.no-ipvs.yaml)
  log "no IPVS in this kernel (/proc/net/ip_vs): adding deploy/compose.no-ipvs.yaml (DNS round robin, host-mode port)"
fi
export IRLGRID_TOKEN=swarm-$RANDOM$RANDOM$RANDOM # for the API calls here only
printf '%s\n' "$IRLGRID_TOKEN" >"$work/irlgrid_token"
worker_token=swarm-worker-$RANDOM$RANDOM$RANDOM
printf '%s\n' "$worker_token" >"$work/irlgrid_worker_token"
port=$($REL free-port)
URL="http://127.0.0.1:$port"
env -u IRLGRID_TOKEN IRLGRID_IMAGE="$image" IRLGRID_TOKEN_SECRET="$work/irlgrid_token" \
  IRLGRID_WORKER_TOKEN_SECRET="$work/irlgrid_worker_token" \
  IRLGRID_PORT="$port" IRLGRID_WORKERS=1 IRLGRID_WORKER_JOBS=1 IRLGRID_WORKER_CPUS=1 \
  IRLGRID_WORKER_MEM=1g IRLGRID_LEASE_SECONDS=60 IRLGRID_SHUTDOWN_GRACE=10 \
  IRLGRID_LOG=info IRLGRID_LOG_JSON=1 \
  docker stack deploy --resolve-image never "${files[@]}" "$stack" >"$work/deploy.log" 2>&1 ||
  fail "docker stack deploy: $(cat "$work/deploy.log")"
# Swarm's own note on options it ignores, for the record.
grep -i 'unsupported' "$work/deploy.log" | sed 's/^/  /' || true
for secret in irlgrid_token irlgrid_worker_token; do
  docker secret ls --format '{{.Name}}' | grep -qx "${stack}_$secret" ||
    fail "no secret ${stack}_$secret"
done
t0=$SECONDS
until $REL healthz "$URL" 2>/dev/null | grep -q '^200'; do
  [ $((SECONDS - t0)) -lt 90 ] || fail "coordinator not healthy at $URL after 90 s"
  sleep 1
done
log "stack $stack up; coordinator healthy at $URL (token from the secret)"
code=$(curl -s -o /dev/null -w '%{http_code}' -X POST -H 'Content-Type: application/json' \
  -d '{"reward_grid":{"w1":[1]},"trials":1}' "$URL/api/v1/searches")
[ "$code" = 401 ] || fail "a submission without the token answered $code, want 401"

search() {
  $REL tiny-search "$1" "$2" "$3" "$4" >"$work/$1.json"
  $REL submit "$URL" "$work/$1.json"
}
running_workers() {
  docker service ps -q --filter desired-state=running "${stack}_worker" |
    xargs -r docker inspect -f '{{.Status.State}}' | grep -cx running || true
}
worker_logs() {
  docker service logs --raw --no-trunc "${stack}_worker" >"$work/workers.log" 2>&1 || true
  echo "$work/workers.log"
}
checked() {
  local what=$1 out rc=0
  shift
  out=$("$@" 2>&1) || rc=$?
  printf '%s\n' "$out" | sed 's/^/  /'
  [ "$rc" = 0 ] || fail "$what"
}

# --- 1. a tiny search ----------------------------------------------------------
s1=$(search swarm-1 2 2 4096)
log "search 1 (2 points x 2 trials) with 1 worker"
$REL wait "$URL" "$s1" 180 || fail "search 1 did not complete"
checked "search 1: exactly-once checks failed" $REL verify "$URL" "$s1" - "$(worker_logs)"
checked "the worker token did more or less than a worker's calls" \
  python3 tests/worker_token_check.py "$URL" "$worker_token" "$s1"

# --- 2. scale to 3 -------------------------------------------------------------
s2=$(search swarm-2 3 2 "${SWARM_CI_ENV_STEPS:-3000000}")
log "search 2 (3 points x 2 trials); docker service scale ${stack}_worker=3"
docker service scale --detach=false "${stack}_worker=3" >/dev/null 2>&1 ||
  fail "docker service scale ${stack}_worker=3 failed"
t0=$SECONDS
until [ "$(running_workers)" = 3 ]; do
  [ $((SECONDS - t0)) -lt 60 ] || fail "$(running_workers) worker tasks running, want 3"
  sleep 1
done
log "  3 worker tasks running ($(docker service ls --filter "name=${stack}_worker" --format '{{.Replicas}}'))"
t0=$SECONDS
until $REL get "$URL" "/api/v1/searches/$s2/jobs" | python3 -c '
import json, sys
jobs = json.loads(sys.stdin.read().split(" ", 1)[1])
busy = {j["worker"].rsplit("/", 1)[0] for j in jobs if j["status"] == "leased"
        and (j.get("progress") or {}).get("env_steps", 0) > 0}
sys.exit(0 if len(busy) >= 3 else 1)'; do
  [ $((SECONDS - t0)) -lt 90 ] || fail "the 3 workers did not all train jobs of search 2 within 90 s"
  sleep 1
done
log "  all 3 workers are training jobs of search 2"

# --- 3. scale back to 1 mid-search -----------------------------------------------
released0=$($REL metric "$URL" irlgrid_leases_released_total)
docker service scale --detach=false "${stack}_worker=1" >/dev/null 2>&1 ||
  fail "docker service scale ${stack}_worker=1 failed"
released=$(($($REL metric "$URL" irlgrid_leases_released_total) - released0))
[ "$released" -ge 2 ] || fail "scaling down released $released lease(s), want 2 (one per stopped worker)"
checked "search 2: a stopped worker used an attempt" python3 -c '
import json, os, sys, urllib.request
# Reads need the token too.
req = urllib.request.Request(sys.argv[1], headers={"Authorization": "Bearer " + os.environ["IRLGRID_TOKEN"]})
jobs = json.load(urllib.request.urlopen(req))
used = [(j["id"], j["attempts"]) for j in jobs if j["attempts"]]
leased = sum(j["status"] == "leased" for j in jobs)
print(f"after the scale-down: {leased} leased (the remaining worker), attempts used {used or 0}")
sys.exit(1 if used or leased > 1 else 0)' "$URL/api/v1/searches/$s2/jobs"
log "  scaled to 1: $released lease(s) handed back to the queue"
$REL wait "$URL" "$s2" 300 || fail "search 2 did not complete"
checked "search 2: exactly-once checks failed" $REL verify "$URL" "$s2" - "$(worker_logs)"
log "PASSED"
