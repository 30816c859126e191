#!/usr/bin/env bash
# Coordinator kills around extensions: a coordinator and 2
# workers run a tiny search while a loop sends `POST .../extend` (alternately
# one more trial per point and one more w1 value) and SIGKILLs the
# coordinator 0-250 ms later, so that kills land before, while and after the
# extension commits, and while workers lease and upload. After each restart
# the same extension is sent again: it must be applied once and only once
# (200 if the kill lost it, 400 "already" if it had committed; an extension
# answered 200 before the kill must never be lost), and the jobs must be
# exactly points x trials with the job-seed rule's seeds (`rel.py
# grid-check`). Then the search must complete with every job done exactly
# once (`rel.py verify`) and the grid still exact.
#
# Quick mode: 6 extensions (2 points x 1 trial grows to 5 x 4). Full
# (IRLGRID_RELIABILITY=full): 12 extensions (to 8 x 7).
set -euo pipefail
SCRIPT_NAME=extend_crash
source "$(dirname "$0")/lib.sh"
need_bin

if [ "$FULL" = 1 ]; then
  ROUNDS=12 STEPS=4096 LIMIT=600
else
  ROUNDS=6 STEPS=2048 LIMIT=120
fi
NWORKERS=2
LEASE=5
SEED=11

new_site extend-crash
trap cleanup EXIT

start_coordinator "127.0.0.1:$PORT" "$DB" "$CLOG" --lease-seconds "$LEASE"
wait_healthy "$URL" 30 || { fail "coordinator did not become healthy"; finish; }
$REL tiny-search extend-crash 2 1 "$STEPS" >"$WORK/search.json"
SID="$($REL submit "$URL" "$WORK/search.json")"
log "search $SID: 2 points x 1 trial on $URL, lease ${LEASE}s"
for i in $(seq 1 "$NWORKERS"); do
  start_worker "w$i" "$URL" "$WORK/spool-w$i" "$WORK/worker-w$i.log"
done

T0=$SECONDS
TRIALS=1
W1=1.0                      # tiny-search's grid is 0.5, 1.0; new values go above
APPLIED_BEFORE_KILL=0 LOST_BY_KILL=0
for r in $(seq 1 "$ROUNDS"); do
  if [ $((r % 2)) = 1 ]; then
    TRIALS=$((TRIALS + 1)); BODY="{\"trials\": $TRIALS}"
  else
    W1="$(python3 -c "print($W1 + 0.75)")"; BODY="{\"reward_grid\": {\"w1\": [$W1]}}"
  fi
  # The extension and, 0-250 ms later, the kill.
  $REL post "$URL" "/api/v1/searches/$SID/extend" "$BODY" >"$WORK/first-$r.out" 2>&1 &
  POST=$!
  sleep "$(rand_between 0 250)"
  kill -9 "$COORD_PID" 2>/dev/null || true
  wait "$COORD_PID" 2>/dev/null || true
  wait "$POST" 2>/dev/null || true
  first="$(head -c 3 "$WORK/first-$r.out")"
  sleep "$(rand_between 0 500)"
  start_coordinator "127.0.0.1:$PORT" "$DB" "$CLOG" --lease-seconds "$LEASE"
  wait_healthy "$URL" 30 || { fail "coordinator did not restart after kill #$r"; break; }
  # The same extension again: applied exactly once.
  again="$($REL post "$URL" "/api/v1/searches/$SID/extend" "$BODY")"
  case "$first:${again:0:3}" in
    200:400) APPLIED_BEFORE_KILL=$((APPLIED_BEFORE_KILL + 1)) ;;
    200:*) fail "round $r: extension $BODY answered 200 before the kill, then $again (lost?)" ;;
    *:200) LOST_BY_KILL=$((LOST_BY_KILL + 1)) ;;
    *:400) APPLIED_BEFORE_KILL=$((APPLIED_BEFORE_KILL + 1)) ;;   # committed, answer lost
    *) fail "round $r: extension $BODY: first ${first:-none}, again $again" ;;
  esac
  case "$again" in
    200*|400*already*) ;;
    *) fail "round $r: retry of $BODY answered $again" ;;
  esac
  $REL grid-check "$URL" "$SID" "$SEED" >"$WORK/grid-$r.out" || {
    cat "$WORK/grid-$r.out"; fail "round $r: jobs are not exactly points x trials"; }
done
log "$ROUNDS extensions, each with a SIGKILL: $APPLIED_BEFORE_KILL committed before the kill, $LOST_BY_KILL lost by it and applied on retry"
check "every extension applied once" test $((APPLIED_BEFORE_KILL + LOST_BY_KILL)) -eq "$ROUNDS"
$REL wait "$URL" "$SID" "$LIMIT" || fail "search not completed within ${LIMIT}s after the last extension"
ELAPSED=$((SECONDS - T0))
if $REL grid-check "$URL" "$SID" "$SEED"; then
  pass "final grid: exactly points x trials with the rule's seeds"
else
  fail "final grid is not exactly points x trials"
fi
logs=("$WORK"/worker-*.log)
if $REL verify "$URL" "$SID" "$DB" "${logs[@]}"; then
  pass "exactly-once checks (verify)"
else
  fail "exactly-once checks (verify)"
fi
echo "FIGURES: extend_crash rounds=$ROUNDS committed_before_kill=$APPLIED_BEFORE_KILL lost_by_kill=$LOST_BY_KILL seconds=$ELAPSED"
finish
