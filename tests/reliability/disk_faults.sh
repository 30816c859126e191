#!/usr/bin/env bash
# Disk full and read-only database, on a small tmpfs holding the database
# (needs root and `mount`; otherwise SKIPPED — the same error mapping is
# tested without root by `cargo test -p coordinator`: tests/api/faults.rs,
# src/store/error_tests.rs and src/store/queue/tests.rs).
#
# Disk full: while 2 workers run a tiny search, a file fills the tmpfs.
# Writes that need space must answer 503 with a JSON {"error": "database
# unavailable: database or disk is full ..."} and Retry-After, never a 500;
# /healthz must answer 503 while its probe write fails. The file is deleted:
# /healthz 200 again, a new search is accepted, the search completes with
# every job done exactly once and `pragma integrity_check` ok.
#
# Read-only: Linux refuses to remount a file system read-only while a
# process holds a file open for writing (EBUSY), so the coordinator is
# killed, the tmpfs remounted read-only, and the coordinator started on it:
# reads must work, writes and /healthz must answer 503 (or the coordinator
# must refuse to start with a clear message). Remounted read-write and
# restarted: healthy, intact.
set -euo pipefail
SCRIPT_NAME=disk_faults
source "$(dirname "$0")/lib.sh"

if [ "$(id -u)" != 0 ]; then
  echo "SKIPPED: disk_faults (needs root to mount a tmpfs)"
  exit 0
fi
if ! command -v mount >/dev/null 2>&1; then
  echo "SKIPPED: disk_faults (no mount command)"
  exit 0
fi
need_bin

WORK="${DEBUG_WORK:-$(mktemp -d -t irlgrid-disk.XXXXXX)}"
MNT="$WORK/mnt"
mkdir -p "$MNT"
if ! mount -t tmpfs -o size=24m tmpfs "$MNT" 2>"$WORK/mount.err"; then
  echo "SKIPPED: disk_faults (cannot mount a tmpfs: $(head -1 "$WORK/mount.err"))"
  rm -rf "$WORK"
  exit 0
fi
extra_cleanup() {
  umount "$MNT" 2>/dev/null || umount -l "$MNT" 2>/dev/null || true
}
trap cleanup EXIT

PORT="$($REL free-port)"
URL="http://127.0.0.1:$PORT"
DB="$MNT/grid.db"
CLOG="$WORK/coordinator.log"
HOLD=6
[ "$FULL" = 1 ] && HOLD=20

start_coordinator "127.0.0.1:$PORT" "$DB" "$CLOG" --lease-seconds 5
wait_healthy "$URL" 30 || { fail "coordinator did not become healthy"; finish; }
$REL tiny-search disk-faults 4 3 32768 >"$WORK/search.json"
SID="$($REL submit "$URL" "$WORK/search.json")"
for i in 1 2; do
  start_worker "w$i" "$URL" "$WORK/spool-w$i" "$WORK/worker-w$i.log"
done
# Requests answered with this status since the coordinator started.
status_count() {
  $REL get "$URL" /metrics | { grep '^irlgrid_http_request_duration_seconds_count' || true; } |
    { grep "status=\"$1\"" || true; } | awk '{s+=$2} END {print s+0}'
}
done_jobs() { $REL get "$URL" "/api/v1/searches/$SID" | cut -d' ' -f2- |
  python3 -c 'import json,sys; print(json.load(sys.stdin)["jobs"]["done"])'; }
t0=$SECONDS
until [ "$(done_jobs)" -ge 2 ]; do
  [ $((SECONDS - t0)) -lt 120 ] || { fail "no progress before the fault"; finish; }
  sleep 0.3
done

# ---- disk full ----
log "filling the tmpfs (jobs done so far: $(done_jobs))"
dd if=/dev/zero of="$MNT/fill" bs=64k 2>/dev/null || true
log "tmpfs: $(df -h "$MNT" | tail -1)"
python3 -c "
w1 = [0.25 * (k + 1) for k in range(64)]
import json; print(json.dumps({'name': 'too-big', 'reward_grid': {'w1': w1}, 'trials': 50,
  'training': {'env_steps': 4096}, 'sampling': {'successful_episodes': 2, 'top_k': 2}}))" >"$WORK/big.json"
BIG="$(cat "$WORK/big.json")"
SUBMIT="$($REL post "$URL" /api/v1/searches "$BIG")"
log "submit while full -> ${SUBMIT:0:300}"
check "a search submitted on a full disk is refused with 503 and a clear message" \
  bash -c "[[ '${SUBMIT//\'/}' == 503*'database unavailable: database or disk is full (SQLITE_FULL)'*'retry-after=5' ]]"
FULL_T0=$SECONDS
H503=0 H200=0
while [ $((SECONDS - FULL_T0)) -lt "$HOLD" ]; do
  case "$($REL healthz "$URL")" in 503*) H503=$((H503 + 1)) ;; 200*) H200=$((H200 + 1)) ;; esac
  sleep 0.5
done
HEALTH_FULL="$($REL healthz "$URL")"
log "healthz while full: $H503 x 503, $H200 x 200; last: ${HEALTH_FULL:0:200}"
N503="$(status_count 503)"
N500="$(status_count 500)"
log "coordinator answered $N503 requests with 503 and $N500 with 500 while full"
check "no 500 while the disk was full ($N500)" [ "$N500" = 0 ]
check "the coordinator answered 503 while the disk was full ($N503 answers)" [ "$N503" -ge 1 ]
check "coordinator process survived the full disk" kill -0 "$COORD_PID"

log "space returns"
rm -f "$MNT/fill"
t0=$SECONDS
until case "$($REL healthz "$URL")" in 200*) true ;; *) false ;; esac; do
  [ $((SECONDS - t0)) -lt 30 ] || break
  sleep 0.2
done
RECOVER_S=$((SECONDS - t0))
check "healthz 200 again ${RECOVER_S}s after space returned" bash -c "case \"\$($REL healthz $URL)\" in 200*) true;; *) false;; esac"
SUBMIT2="$($REL post "$URL" /api/v1/searches "$BIG")"
check "the same search is accepted once space returned (${SUBMIT2:0:60})" bash -c "[[ '$SUBMIT2' == 201* ]]"
if [[ "$SUBMIT2" == 201* ]]; then
  # Not run: cancelled at once (the check above is that it was accepted).
  SID_BIG="$(echo "${SUBMIT2#201 }" | python3 -c 'import json,sys; print(json.loads(sys.stdin.read().split(" retry-after")[0])["id"])')"
  $REL post "$URL" "/api/v1/searches/$SID_BIG/cancel" '{}' >/dev/null
fi
if $REL wait "$URL" "$SID" 180; then
  logs=("$WORK"/worker-*.log)
  if $REL verify "$URL" "$SID" "$DB" "${logs[@]}"; then pass "exactly-once after the full disk"; else fail "exactly-once after the full disk"; fi
else
  fail "search not completed after space returned"
fi
RETRIES="$(grep -h 'will retry\|backing off' "$WORK"/worker-*.log | grep -c '503' || true)"
log "worker calls that met a 503 and were retried: $RETRIES"

# ---- read-only ----
log "read-only: kill the coordinator, remount the tmpfs read-only, start it on it"
kill -9 "$COORD_PID"; wait "$COORD_PID" 2>/dev/null || true
RO_LOG="$WORK/coordinator-ro.log"
if mount -o remount,ro "$MNT" 2>"$WORK/remount.err"; then
  start_coordinator "127.0.0.1:$PORT" "$DB" "$RO_LOG" --lease-seconds 5
  t0=$SECONDS
  RO_OUTCOME=""
  while [ $((SECONDS - t0)) -lt 20 ]; do
    if ! kill -0 "$COORD_PID" 2>/dev/null; then RO_OUTCOME=exited; break; fi
    case "$($REL healthz "$URL")" in 0*) ;; *) RO_OUTCOME=serving; break ;; esac
    sleep 0.2
  done
  if [ "$RO_OUTCOME" = serving ]; then
    HRO="$($REL healthz "$URL")"
    LIST="$($REL get "$URL" /api/v1/searches | cut -c1-3)"
    SUBRO="$($REL post "$URL" /api/v1/searches "$(cat "$WORK/search.json")")"
    log "read-only: healthz -> ${HRO:0:200}; list -> $LIST; submit -> ${SUBRO:0:200}"
    check "read-only database: healthz 503" bash -c "[[ '$HRO' == 503*'database unavailable'* ]]"
    check "read-only database: reads still served" [ "$LIST" = 200 ]
    check "read-only database: a write answers 503 with a clear message" \
      bash -c "[[ '${SUBRO//\'/}' == 503*'database unavailable'* ]]"
    RO_N500="$(status_count 500)"
    check "read-only database: no 500" [ "$RO_N500" = 0 ]
    kill -9 "$COORD_PID"; wait "$COORD_PID" 2>/dev/null || true
  else
    MSG="$(grep -i 'error' "$RO_LOG" | tail -1 | cut -c1-300)"
    log "read-only: the coordinator refused to start: $MSG"
    check "read-only database: refused to start with a message naming the database" \
      bash -c "[[ '${MSG//\'/}' == *database* ]]"
  fi
  mount -o remount,rw "$MNT"
else
  fail "remount read-only: $(head -1 "$WORK/remount.err")"
fi
start_coordinator "127.0.0.1:$PORT" "$DB" "$CLOG" --lease-seconds 5
check "coordinator healthy again on the read-write file system" wait_healthy "$URL" 30
check "integrity_check ok after both faults" bash -c "[ \"\$($REL integrity $DB)\" = ok ]"
echo "FIGURES: disk_faults tmpfs=24m full_hold_s=$HOLD answers_503=$N503 answers_500=$N500 healthz_503=$H503 healthz_200=$H200 recovered_s=$RECOVER_S worker_retries_on_503=$RETRIES readonly=${RO_OUTCOME:-n/a}"
finish
