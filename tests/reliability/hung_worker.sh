#!/usr/bin/env bash
# Slow or hung worker, with real processes (the API-level versions are
# coordinator/tests/api/leases.rs: expired_lease_goes_to_another_worker...,
# failures_retry_until_max_attempts...; and src/store/queue/tests.rs:
# expired_lease_is_requeued_then_fails_after_max_attempts).
#
# A: worker "hung" leases a job and is frozen with SIGSTOP past its lease
#    (3 s): the lease expires, worker "live" gets the job and finishes it.
#    SIGCONT: the thawed worker learns its lease is gone (409) and drops
#    the job; the job keeps live's result.
# B: a search with max_attempts 2 and only "hung" running: it is frozen
#    with SIGSTOP on each of its two leases; after the second expiry the
#    job is failed, and GET /api/v1/jobs/{id} shows status failed, 2
#    attempts and the last error ("lease expired (owner hung/0); all 2 attempts used"); the
#    result document's notes name it too.
set -euo pipefail
SCRIPT_NAME=hung_worker
source "$(dirname "$0")/lib.sh"
need_bin

LEASE=3
WORK="$(mktemp -d -t irlgrid-hung.XXXXXX)"
extra_cleanup() { [ -n "${HUNG:-}" ] && kill -CONT "$HUNG" 2>/dev/null || true; }
trap cleanup EXIT
PORT="$($REL free-port)"
URL="http://127.0.0.1:$PORT"
DB="$WORK/grid.db"
start_coordinator "127.0.0.1:$PORT" "$DB" "$WORK/coordinator.log" --lease-seconds "$LEASE"
wait_healthy "$URL" 30 || { fail "coordinator did not become healthy"; finish; }

job() { # job SEARCH -> JSON of its first job's detail
  local id
  id="$($REL get "$URL" "/api/v1/searches/$1/jobs" | cut -d' ' -f2- |
    python3 -c 'import json,sys; print(json.load(sys.stdin)[0]["id"])')"
  $REL get "$URL" "/api/v1/jobs/$id" | cut -d' ' -f2-
}
field() { python3 -c 'import json,sys; v=json.load(sys.stdin).get(sys.argv[1]); print(v if v is not None else "")' "$1"; }
wait_field() { # wait_field SEARCH FIELD VALUE LIMIT
  local t0=$SECONDS
  until [ "$(job "$1" | field "$2")" = "$3" ]; do
    [ $((SECONDS - t0)) -lt "$4" ] || return 1
    sleep 0.1
  done
}

# ---- A ----
start_worker hung "$URL" "$WORK/spool-hung" "$WORK/worker-hung.log"
HUNG=$WPID
$REL tiny-search hung-a 1 1 524288 >"$WORK/a.json"
SA="$($REL submit "$URL" "$WORK/a.json")"
wait_field "$SA" status leased 30 || fail "A: hung never leased the job"
kill -STOP "$HUNG"
STOP_AT=$SECONDS
log "A: worker hung (pid $HUNG) frozen with its lease"
start_worker live "$URL" "$WORK/spool-live" "$WORK/worker-live.log"
LIVE=$WPID
if wait_field "$SA" status done 120; then
  D="$(job "$SA")"
  W="$(echo "$D" | field worker)" N="$(echo "$D" | field lease_count)" A="$(echo "$D" | field attempts)"
  check "A: the frozen worker's job was re-leased and done by live ($W, $N leases, $A attempt lost) $((SECONDS - STOP_AT))s after SIGSTOP" \
    bash -c "[[ '$W' == live/* ]] && [ '$N' = 2 ] && [ '$A' = 1 ]"
else
  fail "A: job not done by live"
fi
kill -CONT "$HUNG"
t0=$SECONDS
until grep -q 'lease lost' "$WORK/worker-hung.log"; do
  [ $((SECONDS - t0)) -lt 60 ] || break
  sleep 0.2
done
check "A: thawed worker hung learned its lease was lost (409) and dropped the job" \
  grep -q 'lease lost' "$WORK/worker-hung.log"
check "A: thawed worker hung is still running" kill -0 "$HUNG"
if $REL verify "$URL" "$SA" "$DB" "$WORK"/worker-*.log >"$WORK/verify-a.txt"; then
  pass "A: exactly-once checks"
else
  cat "$WORK/verify-a.txt"; fail "A: exactly-once checks"
fi
kill -TERM "$LIVE"; wait "$LIVE" 2>/dev/null || true

# ---- B ----
python3 - "$WORK/a.json" >"$WORK/b.json" <<'EOF'
import json, sys
b = json.load(open(sys.argv[1]))
b.update(name="hung-b", max_attempts=2, seed=99)
print(json.dumps(b))
EOF
SB="$($REL submit "$URL" "$WORK/b.json")"
for round in 1 2; do
  if wait_field "$SB" status leased 60; then
    kill -STOP "$HUNG"
    log "B: hung frozen on lease $round"
    if [ "$round" = 1 ]; then
      wait_field "$SB" status queued 30 || fail "B: lease 1 did not expire"
      kill -CONT "$HUNG"
    else
      wait_field "$SB" status failed 30 || fail "B: job not failed after the second expiry"
      kill -CONT "$HUNG"
    fi
  else
    fail "B: hung did not lease the job (round $round)"
  fi
done
D="$(job "$SB")"
log "B: GET /api/v1/jobs/{id} -> $(echo "$D" | python3 -c 'import json,sys; d=json.load(sys.stdin); print({k: d.get(k) for k in ("status","attempts","lease_count","last_error","worker")})')"
ST="$(echo "$D" | field status)" AT="$(echo "$D" | field attempts)" ERR="$(echo "$D" | field last_error)"
check "B: job failed after max_attempts=2 lost leases (status $ST, attempts $AT)" \
  bash -c "[ '$ST' = failed ] && [ '$AT' = 2 ]"
check "B: its last error is visible in the API: '$ERR'" \
  bash -c "[[ '$ERR' == 'lease expired (owner hung/0); all 2 attempts used' ]]"
$REL wait "$URL" "$SB" 30 || true
NOTES="$($REL get "$URL" "/api/v1/searches/$SB/results" | cut -d' ' -f2- |
  python3 -c 'import json,sys; print(json.load(sys.stdin)["notes"])')"
check "B: the result document's notes name the failure" bash -c "[[ \"\$1\" == *'lease expired'* ]]" _ "$NOTES"
check "B: worker hung still running after both freezes" kill -0 "$HUNG"
echo "FIGURES: hung_worker lease_s=$LEASE A_reassigned=yes B_attempts=$AT B_status=$ST"
finish
