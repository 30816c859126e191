#!/usr/bin/env bash
# Network cut: worker "cut" leases a job, then loses its network path to the
# coordinator for longer than its lease (3 s). Worker "free" (which can
# reach the coordinator) must get the job once the lease expires and finish
# it. The cut-off worker finishes its training meanwhile; when its network
# returns its stale upload must be refused with 409 (worker log "result
# refused; dropped", coordinator metric of rejected uploads), and it must
# carry on with new work: with "free" stopped, it alone completes a second
# search.
#
# Two ways to cut (IRLGRID_NETCUT=netns|proxy; default netns when running
# as root with `ip` and network namespaces, else proxy):
#   netns: "cut" runs in its own network namespace joined to the host by a
#          veth pair; the cut is `ip link set <veth> down` inside it.
#   proxy: "cut" talks to the coordinator through tests/reliability/
#          tcp_proxy.py; the cut is a SIGKILL of the proxy, the repair a
#          restart on the same port.
set -euo pipefail
SCRIPT_NAME=netcut
source "$(dirname "$0")/lib.sh"
need_bin

LEASE=3
STEPS=393216
[ "$FULL" = 1 ] && STEPS=262144
WORK="$(mktemp -d -t irlgrid-netcut.XXXXXX)"
NS="irlcut$$"
VH="irh$$"
VN="irn$$"
MODE="${IRLGRID_NETCUT:-}"
if [ -z "$MODE" ]; then
  MODE=proxy
  if [ "$(id -u)" = 0 ] && command -v ip >/dev/null 2>&1 && ip netns add "$NS" 2>/dev/null; then
    ip netns del "$NS"
    MODE=netns
  fi
fi
extra_cleanup() {
  if [ "$MODE" = netns ]; then
    ip link del "$VH" 2>/dev/null || true
    ip netns del "$NS" 2>/dev/null || true
  fi
}
trap cleanup EXIT
log "cut method: $MODE"
echo "METHOD: netcut uses $MODE"

export IRLGRID_TOKEN="netcut-$$-$RANDOM"
PORT="$($REL free-port)"
URL="http://127.0.0.1:$PORT"
DB="$WORK/grid.db"
if [ "$MODE" = netns ]; then
  SUB="10.$((200 + RANDOM % 50)).$((RANDOM % 250)).$((RANDOM % 60 * 4))"
  HOST_IP="${SUB%.*}.$((${SUB##*.} + 1))"
  NS_IP="${SUB%.*}.$((${SUB##*.} + 2))"
  ip netns add "$NS"
  ip link add "$VH" type veth peer name "$VN"
  ip link set "$VN" netns "$NS"
  ip addr add "$HOST_IP/30" dev "$VH"
  ip link set "$VH" up
  ip -n "$NS" addr add "$NS_IP/30" dev "$VN"
  ip -n "$NS" link set lo up
  ip -n "$NS" link set "$VN" up
  # Listen on every address (a token is set), so "free" uses loopback and
  # only the namespace's path is cut.
  BIND="0.0.0.0:$PORT"
  CUT_URL="http://$HOST_IP:$PORT"
  net_cut() { ip -n "$NS" link set "$VN" down; }
  net_repair() { ip -n "$NS" link set "$VN" up; }
  run_cut_worker() {
    RUST_LOG=info IRLGRID_LOG_JSON=1 ip netns exec "$NS" \
      "$BIN" worker --coordinator "$CUT_URL" --jobs 1 --name cut --spool-dir "$WORK/spool-cut" \
      >>"$WORK/worker-cut.log" 2>&1 &
    CUT_PID=$!
    PIDS+=("$CUT_PID")
  }
else
  BIND="127.0.0.1:$PORT"
  PPORT="$($REL free-port)"
  CUT_URL="http://127.0.0.1:$PPORT"
  start_proxy() {
    python3 "$REL_DIR/tcp_proxy.py" "$PPORT" 127.0.0.1 "$PORT" &
    PROXY_PID=$!
    PIDS+=("$PROXY_PID")
    sleep 0.3
  }
  start_proxy
  net_cut() { kill -9 "$PROXY_PID"; wait "$PROXY_PID" 2>/dev/null || true; }
  net_repair() { start_proxy; }
  run_cut_worker() {
    start_worker cut "$CUT_URL" "$WORK/spool-cut" "$WORK/worker-cut.log"
    CUT_PID=$WPID
  }
fi

start_coordinator "$BIND" "$DB" "$WORK/coordinator.log" --lease-seconds "$LEASE"
wait_healthy "$URL" 30 || { fail "coordinator did not become healthy"; finish; }
run_cut_worker
$REL tiny-search netcut-1 1 1 "$STEPS" >"$WORK/s1.json"
SID1="$($REL submit "$URL" "$WORK/s1.json")"

jobs_json() { $REL get "$URL" "/api/v1/searches/$1/jobs" | cut -d' ' -f2-; }
job_field() { # job_field SEARCH FIELD -> the one job's field
  jobs_json "$1" | python3 -c 'import json,sys; print(json.load(sys.stdin)[0].get(sys.argv[1]))' "$2"
}
t0=$SECONDS
until [ "$(job_field "$SID1" status)" = leased ]; do
  [ $((SECONDS - t0)) -lt 30 ] || { fail "worker cut never leased the job"; finish; }
  sleep 0.1
done
JOB="$(job_field "$SID1" id)"
log "worker cut holds job $JOB ($(job_field "$SID1" worker)); cutting its network"
net_cut
CUT_AT=$SECONDS
start_worker free "$URL" "$WORK/spool-free" "$WORK/worker-free.log"
FREE_PID=$WPID

# The job moves on: done by "free" while "cut" is still cut off.
t0=$SECONDS
until [ "$(job_field "$SID1" status)" = done ]; do
  [ $((SECONDS - t0)) -lt 90 ] || { fail "job $JOB was not re-leased and finished"; break; }
  sleep 0.2
done
MOVED_AFTER=$((SECONDS - CUT_AT))
OWNER="$(job_field "$SID1" worker)"
LEASES="$(job_field "$SID1" lease_count)"
check "job $JOB moved on to worker free (owner $OWNER, $LEASES leases) ${MOVED_AFTER}s after the cut" \
  bash -c "[[ '$OWNER' == free/* ]] && [ '$LEASES' -ge 2 ]"
# Let the cut-off worker finish its own training before its network returns.
t0=$SECONDS
until grep -q 'job finished; uploading' "$WORK/worker-cut.log"; do
  [ $((SECONDS - t0)) -lt 90 ] || { fail "worker cut never finished its job"; break; }
  sleep 0.2
done
CUT_FOR=$((SECONDS - CUT_AT))
log "repairing the network after ${CUT_FOR}s"
net_repair
t0=$SECONDS
until grep -q 'result refused; dropped' "$WORK/worker-cut.log"; do
  [ $((SECONDS - t0)) -lt 90 ] || break
  sleep 0.2
done
REFUSED_AFTER=$((SECONDS - t0))
line="$(grep 'result refused; dropped' "$WORK/worker-cut.log" | head -1 || true)"
check "worker cut's stale upload of job $JOB was refused (after ${REFUSED_AFTER}s): ${line:0:200}" \
  bash -c "[[ '$line' == *'\"job_id\":$JOB'* ]]"
REJ="$($REL metric "$URL" irlgrid_uploads_rejected_total)"
R409="$($REL get "$URL" /metrics | { grep '^irlgrid_http_request_duration_seconds_count' || true; } |
  { grep 'route="/api/v1/jobs/{id}/result",status="409"' || true; } | awk '{s+=$2} END {print s+0}')"
check "coordinator counted the refused upload (uploads_rejected_total=$REJ, 409 on the result route: $R409)" \
  bash -c "[ '$REJ' -ge 1 ] && [ '$R409' -ge 1 ]"
check "worker cut is still running" kill -0 "$CUT_PID"

# It carries on with new work: "free" stops, a second search goes to "cut".
kill -TERM "$FREE_PID"
wait "$FREE_PID" 2>/dev/null || true
$REL tiny-search netcut-2 1 2 16384 >"$WORK/s2.json"
SID2="$($REL submit "$URL" "$WORK/s2.json")"
if $REL wait "$URL" "$SID2" 120; then
  owners="$(jobs_json "$SID2" | python3 -c 'import json,sys; print(" ".join(sorted({j["worker"] for j in json.load(sys.stdin)})))')"
  check "worker cut completed the second search alone (owners: $owners)" \
    bash -c "[[ '$owners' == 'cut/0' ]]"
else
  fail "second search not completed by worker cut"
fi
ACC="$($REL accepted-ids "$WORK/worker-cut.log" | wc -w)"
if $REL verify "$URL" "$SID1" "$DB" "$WORK/worker-free.log" >"$WORK/verify.txt"; then
  pass "search 1 exactly-once checks"
else
  cat "$WORK/verify.txt"
  fail "search 1 exactly-once checks"
fi
echo "FIGURES: netcut method=$MODE lease_s=$LEASE cut_s=$CUT_FOR job_moved_after_s=$MOVED_AFTER stale_upload_refused_after_repair_s=$REFUSED_AFTER uploads_rejected=$REJ cut_worker_accepted_after=$ACC"
finish
