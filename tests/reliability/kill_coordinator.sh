#!/usr/bin/env bash
# Coordinator kills: a coordinator and 3 workers run a tiny search while a
# loop SIGKILLs the coordinator at random instants (0.2-1.5 s after it serves again, so
# kills land while workers lease, heartbeat and upload, and while a reader
# polls the results document so that partial aggregation runs), keeps it
# down 0-1.5 s, and restarts it on the same database file and port. The
# workers are never touched: they must resume on their own. Once the search
# completes the coordinator is killed once more right away (before or while
# it caches the final document) and restarted. Then: completed, every job
# done exactly once, every result a worker saw accepted is in the database,
# nothing leased, final document cached, `pragma integrity_check` ok.
#
# Every (point, trial) runs as two solver variants, PPO and a tiny
# trajectory optimizer. Quick mode: 36 jobs, at least 12 kills.
# IRLGRID_RELIABILITY=full: 64 jobs,
# at least 40 kills.
set -euo pipefail
SCRIPT_NAME=kill_coordinator
source "$(dirname "$0")/lib.sh"
need_bin

if [ "$FULL" = 1 ]; then
  POINTS=8 TRIALS=4 STEPS=131072 MIN_KILLS=40 LIMIT=900
else
  POINTS=6 TRIALS=3 STEPS=65536 MIN_KILLS=12 LIMIT=240
fi
NWORKERS=3
LEASE=5

new_site kill-coord
trap cleanup EXIT

start_coordinator "127.0.0.1:$PORT" "$DB" "$CLOG" --lease-seconds "$LEASE"
wait_healthy "$URL" 30 || { fail "coordinator did not become healthy"; finish; }
$REL tiny-search kill-coordinator "$POINTS" "$TRIALS" "$STEPS" mixed >"$WORK/search.json"
SID="$($REL submit "$URL" "$WORK/search.json")"
log "search $SID: $((POINTS * TRIALS * 2)) jobs on $URL, lease ${LEASE}s"
declare -A WP
for i in $(seq 1 "$NWORKERS"); do
  start_worker "w$i" "$URL" "$WORK/spool-w$i" "$WORK/worker-w$i.log"
  WP[w$i]=$WPID
done

# A reader polling the results document (partial aggregation) throughout.
(
  while true; do
    $REL get "$URL" "/api/v1/searches/$SID/results" >/dev/null 2>&1 || true
    sleep 0.1
  done
) &
PIDS+=($!)

searching() {
  local s
  s="$($REL get "$URL" "/api/v1/searches/$SID" 2>/dev/null | cut -d' ' -f2- |
    python3 -c 'import json,sys; print(json.load(sys.stdin)["status"])' 2>/dev/null || echo down)"
  [ "$s" != completed ]
}

T0=$SECONDS
KILLS=0 DOWN_MS=0
restart() {
  local down
  down="$(rand_ms 0 1500)"
  sleep "$(ms_to_s "$down")"
  DOWN_MS=$((DOWN_MS + down))
  start_coordinator "127.0.0.1:$PORT" "$DB" "$CLOG" --lease-seconds "$LEASE"
  # Kill again only once it serves (a kill during start-up and migration
  # is covered too: the first sleep below may be shorter than the start).
  wait_healthy "$URL" 30 || fail "coordinator did not restart after kill #$KILLS"
}
while searching; do
  if [ $((SECONDS - T0)) -gt "$LIMIT" ]; then
    fail "search not completed after ${LIMIT}s"
    break
  fi
  sleep "$(rand_between 200 1500)"
  kill -9 "$COORD_PID" 2>/dev/null || true
  wait "$COORD_PID" 2>/dev/null || true
  KILLS=$((KILLS + 1))
  restart
done
KILLS_RUNNING=$KILLS
log "search completed after $KILLS kills"
# Kills after completion until the minimum count is reached: right after
# completion the coordinator may still be building and caching the final
# document; later kills hit an idle coordinator with workers long-polling.
while [ "$KILLS" -lt "$MIN_KILLS" ]; do
  sleep "$(rand_between 0 600)"
  kill -9 "$COORD_PID" 2>/dev/null || true
  wait "$COORD_PID" 2>/dev/null || true
  KILLS=$((KILLS + 1))
  restart
done
ELAPSED=$((SECONDS - T0))
log "$KILLS SIGKILLs of the coordinator; ${ELAPSED}s; down ${DOWN_MS} ms in all"
$REL wait "$URL" "$SID" 60 || fail "search not completed after the last restart"

logs=("$WORK"/worker-*.log)
if $REL verify "$URL" "$SID" "$DB" "${logs[@]}"; then
  pass "exactly-once checks (verify)"
else
  fail "exactly-once checks (verify)"
fi
# Workers resumed on their own: every worker process started at the
# beginning is still alive, and every one of them had a result accepted.
for i in $(seq 1 "$NWORKERS"); do
  n="$($REL accepted-ids "$WORK/worker-w$i.log" | wc -w)"
  check "worker w$i is still running and had results accepted ($n)" \
    bash -c "kill -0 ${WP[w$i]} && [ $n -ge 1 ]"
done
RETRIED="$(cat "$WORK"/worker-*.log | { grep -c 'upload failed; will retry' || true; })"
REFUSED_DUP="$(cat "$WORK"/worker-*.log | { grep -c 'result refused; dropped' || true; })"
LEASE_RETRIES="$(cat "$WORK"/worker-*.log | { grep -c 'lease request failed; backing off' || true; })"
log "uploads that met a dead coordinator and were retried: $RETRIED; refused as already accepted: $REFUSED_DUP"
echo "FIGURES: kill_coordinator jobs=$((POINTS * TRIALS * 2)) kills=$KILLS kills_while_running=$KILLS_RUNNING seconds=$ELAPSED down_ms=$DOWN_MS upload_retries_logged=$RETRIED lease_retries_logged=$LEASE_RETRIES refused_after_retry=$REFUSED_DUP"
finish
