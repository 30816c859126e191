#!/usr/bin/env bash
# CI step: irlgrid workers on a real single-node Slurm cluster, started on
# this machine from Debian's slurm-wlm and munge packages with a throw-away
# configuration (nothing under /etc is used or changed). Through
# deploy/slurm/irlgrid-worker.sbatch it checks that
#   1. an array of 2 workers finishes a tiny search, every job done exactly
#      once, and ends by itself (--exit-when-idle) with exit code 0;
#   2. a worker cut off by its time limit (--time=1) hands its jobs back:
#      they return to the queue without using an attempt;
#   3. an array cancelled (scancel) in the middle of a search hands its
#      jobs back the same way, and a resubmitted array finishes the search
#      with every job done exactly once.
# The workers get only the worker token (IRLGRID_WORKER_TOKEN_FILE): after
# search 1 it is checked to lease but not submit or read
# (tests/worker_token_check.py). The token file's mode is checked by the
# script (600 only).
# Where the packages cannot be installed or the daemons do not start, it
# prints "SKIPPED: <reason>" and succeeds. Every daemon and process it
# started is stopped by pid, and its temporary directory removed.
#
#   bash .ci/steps/slurm.sh            (IRLGRID_BIN: the binary to use)
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT=$PWD

log() { printf '[slurm %s] %s\n' "$(date +%T)" "$*"; }
skip() {
  echo "SKIPPED: slurm workers ($*)"
  exit 0
}
fail() {
  echo "FAIL: $*" >&2
  exit 1
}

# --- tools -----------------------------------------------------------------
need=()
for c in slurmctld slurmd sbatch munged python3; do
  command -v "$c" >/dev/null 2>&1 || need+=("$c")
done
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" != 0 ] || ! command -v apt-get >/dev/null 2>&1; then
    skip "missing ${need[*]} and cannot apt-get install slurm-wlm munge"
  fi
  log "installing slurm-wlm munge (missing ${need[*]})"
  if ! { apt-get update -qq &&
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
      slurm-wlm munge python3 >/dev/null; }; then
    skip "apt-get install slurm-wlm munge failed"
  fi
fi
[ "$(id -u)" = 0 ] || skip "the daemons need root here (slurmd runs jobs as their user)"

TARGET="${CARGO_TARGET_DIR:-target}"
BIN="${IRLGRID_BIN:-$TARGET/release/irlgrid}"
if [ ! -x "$BIN" ]; then
  log "building $BIN"
  cargo build --release --bin irlgrid
fi
BIN=$(cd "$(dirname "$BIN")" && pwd)/$(basename "$BIN")
REL="python3 $ROOT/tests/reliability/rel.py"

# --- a throw-away cluster ----------------------------------------------------
T=$(mktemp -d /tmp/irlgrid-slurm.XXXXXX)
chmod 755 "$T"
PIDS=()
SLURM_UP=0
cleanup() {
  local rc=$?
  trap - EXIT INT TERM
  if [ "$rc" -ne 0 ] && [ -d "$T" ]; then
    for f in "$T"/log/*.log "$T"/out/*; do
      [ -f "$f" ] || continue
      echo "--- $f (last lines)"
      tail -n 15 "$f"
    done
  fi
  if [ "$SLURM_UP" = 1 ]; then
    scancel --quiet --user=root --partition=ci 2>/dev/null || true
    scontrol shutdown >/dev/null 2>&1 || true
  fi
  local f p
  for f in slurmd slurmctld munge/munged coordinator; do
    [ -f "$T/$f.pid" ] || continue
    p=$(cat "$T/$f.pid")
    PIDS+=("$p")
  done
  for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
  sleep 1
  for p in "${PIDS[@]}"; do kill -9 "$p" 2>/dev/null || true; done
  rm -rf "$T"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

mkdir -p "$T/state" "$T/spool" "$T/log" "$T/out" "$T/home"
mkdir -m 700 "$T/munge"
head -c 1024 /dev/urandom >"$T/munge/munge.key"
chmod 400 "$T/munge/munge.key"
if ! munged --force --socket="$T/munge/munge.sock" --key-file="$T/munge/munge.key" \
  --log-file="$T/log/munged.log" --pid-file="$T/munge/munged.pid" \
  --seed-file="$T/munge/munged.seed" >/dev/null 2>&1; then
  skip "munged did not start: $(tail -n1 "$T/log/munged.log" 2>/dev/null)"
fi
munge -n -S "$T/munge/munge.sock" | unmunge -S "$T/munge/munge.sock" >/dev/null 2>&1 ||
  skip "munge credentials do not round-trip"

host=$(hostname -s)
ctld_port=$($REL free-port)
slurmd_port=$($REL free-port)
export SLURM_CONF="$T/slurm.conf"
cat >"$SLURM_CONF" <<EOF
ClusterName=irlgridci
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
AuthType=auth/munge
AuthInfo=socket=$T/munge/munge.sock
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation=$T/state
SlurmdSpoolDir=$T/spool
SlurmctldPidFile=$T/slurmctld.pid
SlurmdPidFile=$T/slurmd.pid
SlurmctldLogFile=$T/log/slurmctld.log
SlurmdLogFile=$T/log/slurmd.log
# No cgroups in this container: track job processes by /proc.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
# Slurm's default: SIGTERM, then SIGKILL this many seconds later.
KillWait=30
MinJobAge=600
NodeName=$host NodeAddr=127.0.0.1 CPUs=2 RealMemory=2000 State=UNKNOWN
PartitionName=ci Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
slurmctld -f "$SLURM_CONF" >/dev/null 2>&1 || skip "slurmctld did not start: $(tail -n1 "$T/log/slurmctld.log" 2>/dev/null)"
SLURM_UP=1
slurmd -f "$SLURM_CONF" >/dev/null 2>&1 || skip "slurmd did not start: $(tail -n1 "$T/log/slurmd.log" 2>/dev/null)"
t0=$SECONDS
until sinfo -h -o '%T' 2>/dev/null | grep -qx idle; do
  [ $((SECONDS - t0)) -lt 30 ] ||
    skip "the node did not come up idle: $(sinfo -h -o '%T %E' 2>&1 | head -n1)"
  sleep 1
done
log "single-node cluster up: $(sinfo -h -o '%P %D node(s) %c CPUs %T' | head -n1) ($(slurmd -V))"

# --- coordinator, token file ---------------------------------------------------
mkdir -m 700 "$T/home/.irlgrid"
# The admin token for the coordinator and this script's API calls; the
# worker token, the only one the sbatch script reads, for the workers.
admin_token_file="$T/home/.irlgrid/token"
token_file="$T/home/.irlgrid/worker-token"
(umask 077 && head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n' >"$admin_token_file")
(umask 077 && head -c 24 /dev/urandom | od -An -tx1 | tr -d ' \n' >"$token_file")
export IRLGRID_TOKEN
IRLGRID_TOKEN=$(cat "$admin_token_file") # for rel.py's API calls only
port=$($REL free-port)
URL="http://127.0.0.1:$port"
DB="$T/grid.db"
# The default 60 s lease: a job back in the queue within the checks below
# was released, not expired.
RUST_LOG=info IRLGRID_LOG_JSON=1 IRLGRID_TOKEN= IRLGRID_TOKEN_FILE="$admin_token_file" \
  IRLGRID_WORKER_TOKEN_FILE="$token_file" \
  "$BIN" coordinator --bind "127.0.0.1:$port" --db "$DB" >>"$T/log/coordinator.log" 2>&1 &
echo $! >"$T/coordinator.pid"
t0=$SECONDS
until $REL healthz "$URL" 2>/dev/null | grep -q '^200'; do
  [ $((SECONDS - t0)) -lt 30 ] || fail "coordinator not healthy at $URL"
  sleep 0.3
done
log "coordinator at $URL (admin and worker tokens from files)"

# The script refuses a worker token file others can read.
chmod 644 "$token_file"
if out=$(HOME="$T/home" IRLGRID_COORDINATOR=$URL IRLGRID_BIN=$BIN \
  bash deploy/slurm/irlgrid-worker.sbatch 2>&1); then
  fail "the sbatch script ran with a token file of mode 644"
fi
case $out in *"mode 644"*) ;; *) fail "unexpected refusal: $out" ;; esac
chmod 600 "$token_file"
log "the script refuses a token file of mode 644"

# checked WHAT CMD...: runs a check, indenting its report; fails with WHAT.
checked() {
  local what=$1 out rc=0
  shift
  out=$("$@" 2>&1) || rc=$?
  printf '%s\n' "$out" | sed 's/^/  /'
  [ "$rc" = 0 ] || fail "$what"
}
# submit_array ARRAY [sbatch flags...] -> prints the array's job id
submit_array() {
  local array=$1
  shift
  HOME="$T/home" IRLGRID_COORDINATOR=$URL IRLGRID_BIN=$BIN \
    IRLGRID_EXIT_WHEN_IDLE=${EXIT_WHEN_IDLE:-6} IRLGRID_SHUTDOWN_GRACE=10 \
    IRLGRID_SPOOL="$T/home/spool" RUST_LOG=info IRLGRID_LOG_JSON=1 \
    sbatch --parsable --array="$array" --cpus-per-task=1 --mem-per-cpu=400M \
    --output="$T/out/%A_%a.log" --chdir="$T" "$@" deploy/slurm/irlgrid-worker.sbatch |
    cut -d';' -f1
}
# array_gone ID LIMIT: waits until no task of the array is pending or running.
array_gone() {
  local t0=$SECONDS
  while [ -n "$(squeue -h -j "$1" -o %i 2>/dev/null)" ]; do
    [ $((SECONDS - t0)) -lt "$2" ] || fail "array $1 still queued or running after $2 s: $(squeue -j "$1")"
    sleep 1
  done
}
# task_states ID -> "STATE EXITCODE" per array task
task_states() {
  scontrol -o show job "$1" | sed -n 's/.*JobState=\([A-Z_]*\).* ExitCode=\([0-9:]*\).*/\1 \2/p' | sort | uniq -c |
    sed 's/^ *//' | paste -sd, -
}
# search NAME POINTS TRIALS ENV_STEPS -> prints the search id
search() {
  $REL tiny-search "$1" "$2" "$3" "$4" >"$T/$1.json"
  $REL submit "$URL" "$T/$1.json"
}
# handed_back ID: no job leased, none with an attempt used; prints figures.
handed_back() {
  $REL get "$URL" "/api/v1/searches/$1/jobs" | python3 -c '
import json, sys
status, body = sys.stdin.read().split(" ", 1)
jobs = json.loads(body)
leased = [j["id"] for j in jobs if j["status"] == "leased"]
used = [(j["id"], j["attempts"]) for j in jobs if j["attempts"]]
relet = [j["id"] for j in jobs if j["status"] == "queued" and j["lease_count"] > 0]
if leased or used or not relet:
    print(f"leased {leased}, attempts used {used}, handed back {relet}")
    sys.exit(1)
done = sum(j["status"] == "done" for j in jobs)
print(f"{len(relet)} job(s) handed back to the queue, none leased, no attempt used; {done} done")'
}
# wait_leased ID N: waits until N jobs are leased and training.
wait_leased() {
  local t0=$SECONDS
  until $REL get "$URL" "/api/v1/searches/$1/jobs" | python3 -c '
import json, sys
status, body = sys.stdin.read().split(" ", 1)
jobs = json.loads(body)
n = sum(j["status"] == "leased" and (j.get("progress") or {}).get("env_steps", 0) > 0 for j in jobs)
sys.exit(0 if n >= int(sys.argv[1]) else 1)' "$2"; do
    [ $((SECONDS - t0)) -lt 60 ] || fail "fewer than $2 jobs of search $1 training after 60 s"
    sleep 1
  done
}

# --- 1. an array of 2 workers finishes a tiny search, then ends -----------------
s1=$(search slurm-1 2 2 4096)
a1=$(submit_array 0-1)
log "search 1 (2 points x 2 trials): array $a1 of 2 workers"
$REL wait "$URL" "$s1" 180 || fail "search 1 did not complete"
checked "search 1: exactly-once checks failed" $REL verify "$URL" "$s1" "$DB" "$T"/out/"$a1"_*.log
array_gone "$a1" 60
states=$(task_states "$a1")
[ "$states" = "2 COMPLETED 0:0" ] || fail "array $a1 tasks: $states, want 2 COMPLETED 0:0"
log "  the array ended by itself once idle: $states"
checked "the worker token did more or less than a worker's calls" \
  python3 tests/worker_token_check.py "$URL" "$(cat "$token_file")" "$s1"

# --- 2. the time limit cuts a worker off mid-job ---------------------------------
# Jobs far longer than the limit; Slurm checks limits about every 30 s.
s2=$(search slurm-2 1 1 50000000)
a2=$(submit_array 0-0 --time=1)
log "search 2 (1 long job): array $a2 with --time=1 (cut off within 60-90 s)"
wait_leased "$s2" 1
array_gone "$a2" 150
states=$(task_states "$a2")
case $states in *TIMEOUT*) ;; *) fail "array $a2 tasks: $states, want TIMEOUT" ;; esac
log "  array $a2: $states"
checked "search 2: the timed-out worker did not hand its job back" handed_back "$s2"
grep -q '"lease released"' "$T"/out/"$a2"_*.log || fail "no 'lease released' in the worker's log"
$REL post "$URL" "/api/v1/searches/$s2/cancel" '{}' >/dev/null

# --- 3. scancel mid-search, then a resubmission finishes it -----------------------
s3=$(search slurm-3 3 2 "${SLURM_CI_ENV_STEPS:-1200000}")
a3=$(submit_array 0-1)
log "search 3 (3 points x 2 trials): array $a3 of 2 workers; scancel once both train"
wait_leased "$s3" 2
released0=$($REL metric "$URL" irlgrid_leases_released_total)
scancel "$a3"
array_gone "$a3" 60
log "  array $a3 after scancel: $(task_states "$a3")"
checked "search 3: the cancelled workers did not hand their jobs back" handed_back "$s3"
released=$(($($REL metric "$URL" irlgrid_leases_released_total) - released0))
[ "$released" -ge 2 ] || fail "search 3: $released lease(s) released on scancel, want 2"
a4=$(submit_array 0-1)
log "  resubmitted: array $a4"
$REL wait "$URL" "$s3" 240 || fail "search 3 did not complete after the resubmission"
checked "search 3: exactly-once checks failed" \
  $REL verify "$URL" "$s3" "$DB" "$T"/out/"$a3"_*.log "$T"/out/"$a4"_*.log
array_gone "$a4" 60
log "PASSED"
