#!/usr/bin/env bash
# Worker chaos: a coordinator (free port, temporary database, short leases)
# and N `irlgrid worker` processes run a tiny search while a loop SIGKILLs a
# random worker every few seconds and restarts it (same name, same spool
# directory) until the search completes. Then: the search completed, every
# job is done exactly once (one result row per job, one output per
# (point, trial), no acceptance logged twice), nothing is left leased, and
# the database passes `pragma integrity_check`.
#
# Every (point, trial) runs as two solver variants, PPO and a tiny
# trajectory optimizer. Quick mode (default): 8x3x2 = 48 jobs, 3 workers.
# IRLGRID_RELIABILITY=full:
# 8x4x2 = 64 jobs, 4 workers, longer training.
set -euo pipefail
SCRIPT_NAME=chaos_workers
source "$(dirname "$0")/lib.sh"
need_bin

if [ "$FULL" = 1 ]; then
  POINTS=8 TRIALS=4 NWORKERS=4 STEPS=131072 LIMIT=900
else
  POINTS=8 TRIALS=3 NWORKERS=3 STEPS=393216 LIMIT=240
fi
LEASE=3
KILL_MIN_MS=1000 KILL_MAX_MS=3000

WORK="$(mktemp -d -t irlgrid-chaos-workers.XXXXXX)"
trap cleanup EXIT
PORT="$($REL free-port)"
URL="http://127.0.0.1:$PORT"
DB="$WORK/grid.db"

log "coordinator on $URL, lease ${LEASE}s, db $DB"
start_coordinator "127.0.0.1:$PORT" "$DB" "$WORK/coordinator.log" --lease-seconds "$LEASE"
wait_healthy "$URL" 30 || { fail "coordinator did not become healthy"; finish; }

$REL tiny-search chaos-workers "$POINTS" "$TRIALS" "$STEPS" mixed >"$WORK/search.json"
SID="$($REL submit "$URL" "$WORK/search.json")"
log "search $SID: $((POINTS * TRIALS * 2)) jobs, $NWORKERS workers, env_steps $STEPS"

declare -A WP
for i in $(seq 1 "$NWORKERS"); do
  start_worker "w$i" "$URL" "$WORK/spool-w$i" "$WORK/worker-w$i.log"
  WP[w$i]=$WPID
done

T0=$SECONDS
KILLS=0 RESTARTS=0 KILLED_MID_JOB=0
while :; do
  if [ $((SECONDS - T0)) -gt "$LIMIT" ]; then
    fail "search not completed after ${LIMIT}s of chaos"
    break
  fi
  sleep "$(rand_between $KILL_MIN_MS $KILL_MAX_MS)"
  victim="w$((RANDOM % NWORKERS + 1))"
  # Is the victim killed mid-job (holding a lease)?
  read -r st held < <($REL state "$URL" "$SID" "$victim")
  [ "$st" = running ] || break
  kill -9 "${WP[$victim]}" 2>/dev/null || true
  wait "${WP[$victim]}" 2>/dev/null || true
  KILLS=$((KILLS + 1))
  [ "$held" -gt 0 ] && KILLED_MID_JOB=$((KILLED_MID_JOB + 1))
  log "SIGKILL $victim (pid ${WP[$victim]}, holding $held lease(s)); kill #$KILLS"
  sleep "$(rand_between 200 1200)"
  start_worker "$victim" "$URL" "$WORK/spool-$victim" "$WORK/worker-$victim.log"
  WP[$victim]=$WPID
  RESTARTS=$((RESTARTS + 1))
done
ELAPSED=$((SECONDS - T0))
log "search finished after ${ELAPSED}s: $KILLS SIGKILLs ($KILLED_MID_JOB mid-job), $RESTARTS restarts"
check "at least 3 workers SIGKILLed mid-job (got $KILLED_MID_JOB of $KILLS)" [ "$KILLED_MID_JOB" -ge 3 ]

# Let live workers drain (nothing left to lease), then check.
sleep 1
logs=("$WORK"/worker-*.log)
if $REL verify "$URL" "$SID" "$DB" "${logs[@]}"; then
  pass "exactly-once checks (verify)"
else
  fail "exactly-once checks (verify)"
fi
EXPIRED="$($REL metric "$URL" irlgrid_leases_expired_total)"
log "leases expired (coordinator metric): $EXPIRED"
check "killed workers' leases expired and were re-leased (expired=$EXPIRED)" [ "$EXPIRED" -ge 1 ]
echo "FIGURES: chaos_workers jobs=$((POINTS * TRIALS * 2)) workers=$NWORKERS kills=$KILLS mid_job=$KILLED_MID_JOB restarts=$RESTARTS leases_expired=$EXPIRED seconds=$ELAPSED"
finish
