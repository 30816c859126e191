#!/usr/bin/env bash
# Soak: a search of 8 points x 5 trials (600 k steps per job, max_attempts
# 20) on 3 workers, under 100 worker SIGKILLs (one every 1.5 s, each victim
# restarted at once under a new name, as a scheduler would) and 10
# coordinator SIGKILLs (one every 15 s, restarted on the same database and
# port). Then: every job done exactly once (`rel.py verify`), and every job
# that is not done printed with its attempts, leases and last error.
#
# Heavy mode only (IRLGRID_RELIABILITY=full); the quick mode prints SKIPPED.
# SOAK_RUNS=N repeats the whole soak N times in a row on fresh databases
# and fails if any run fails.
set -euo pipefail
SCRIPT_NAME=soak
source "$(dirname "$0")/lib.sh"
if [ "$FULL" != 1 ]; then
  echo "SKIPPED: soak (runs only with IRLGRID_RELIABILITY=full)"
  exit 0
fi
need_bin

POINTS=8 TRIALS=5 STEPS=600000 NWORKERS=3 LEASE=5
WORKER_KILLS=100 KILL_EVERY_MS=1500 COORD_EVERY=10 LIMIT=1500
RUNS="${SOAK_RUNS:-1}"

one_run() { # one_run N: the whole soak on a fresh database; sets FAILED
  new_site soak
  start_coordinator "127.0.0.1:$PORT" "$DB" "$CLOG" --lease-seconds "$LEASE"
  wait_healthy "$URL" 30 || { fail "run $1: coordinator did not become healthy"; return; }
  $REL tiny-search soak "$POINTS" "$TRIALS" "$STEPS" >"$WORK/search.json"
  SID="$($REL submit "$URL" "$WORK/search.json")"
  log "run $1: search $SID, $((POINTS * TRIALS)) jobs x $STEPS steps, $NWORKERS workers, lease ${LEASE}s"

  declare -A WP
  local i gen=0 kills=0 ckills=0 st t0=$SECONDS
  for i in $(seq 1 "$NWORKERS"); do
    start_worker "w$i-g0" "$URL" "$WORK/spool-w$i-g0" "$WORK/worker-w$i-g0.log"
    WP[$i]=$WPID
  done
  while [ "$kills" -lt "$WORKER_KILLS" ]; do
    sleep "$(ms_to_s "$KILL_EVERY_MS")"
    i=$((RANDOM % NWORKERS + 1))
    read -r st _ < <($REL state "$URL" "$SID" 2>/dev/null || echo "unknown 0")
    [ "$st" = completed ] && break
    kill -9 "${WP[$i]}" 2>/dev/null || true
    wait "${WP[$i]}" 2>/dev/null || true
    kills=$((kills + 1)) gen=$((gen + 1))
    # A new name: the killed worker's leases are not resumed by anyone.
    start_worker "w$i-g$gen" "$URL" "$WORK/spool-w$i-g$gen" "$WORK/worker-w$i-g$gen.log"
    WP[$i]=$WPID
    if [ $((kills % COORD_EVERY)) = 0 ]; then
      kill -9 "$COORD_PID" 2>/dev/null || true
      wait "$COORD_PID" 2>/dev/null || true
      ckills=$((ckills + 1))
      sleep "$(rand_between 0 1500)"
      start_coordinator "127.0.0.1:$PORT" "$DB" "$CLOG" --lease-seconds "$LEASE"
      wait_healthy "$URL" 30 || fail "run $1: coordinator did not restart after kill #$ckills"
      log "run $1: $kills worker kills, $ckills coordinator kills, $(( SECONDS - t0 ))s"
    fi
  done
  log "run $1: chaos over ($kills worker kills, $ckills coordinator kills); waiting for the search"
  $REL wait "$URL" "$SID" "$LIMIT" || fail "run $1: search not completed within ${LIMIT}s after the chaos"
  local logs=("$WORK"/worker-*.log)
  if $REL verify "$URL" "$SID" "$DB" "${logs[@]}"; then
    pass "run $1: exactly-once checks (verify)"
  else
    fail "run $1: exactly-once checks (verify)"
  fi
  if $REL job-report "$URL" "$SID"; then
    pass "run $1: every job done"
  else
    fail "run $1: some jobs not done (listed above)"
  fi
  echo "FIGURES: soak run=$1 jobs=$((POINTS * TRIALS)) worker_kills=$kills coordinator_kills=$ckills seconds=$((SECONDS - t0))"
  # Stop this run's processes; a failed run keeps its directory.
  if [ "$FAILED" = 1 ]; then KEEP_WORK=1; log "run $1: kept $WORK"; fi
  cleanup
  PIDS=()
}

trap cleanup EXIT
for r in $(seq 1 "$RUNS"); do
  one_run "$r"
  [ "$FAILED" = 0 ] || break
done
finish
