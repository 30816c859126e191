# Shared helpers of the reliability scripts; sourced, not run.
# Needs: bash, python3 (rel.py uses only its standard library).
# IRLGRID_BIN: the irlgrid binary (default: $CARGO_TARGET_DIR or target,
# then release/irlgrid).

REL_DIR="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$REL_DIR/../.." && pwd)"
BIN="${IRLGRID_BIN:-${CARGO_TARGET_DIR:-$ROOT/target}/release/irlgrid}"
REL="python3 $REL_DIR/rel.py"
FULL=0
[ "${IRLGRID_RELIABILITY:-quick}" = full ] && FULL=1

PIDS=()        # every process started, killed by the cleanup trap
FAILED=0

log() { printf '[%s %s] %s\n' "$(date +%H:%M:%S)" "${SCRIPT_NAME:-rel}" "$*"; }
pass() { echo "PASS: $*"; }
fail() { echo "FAIL: $*"; FAILED=1; }
check() { # check "description" command...
  local what="$1"; shift
  if "$@"; then pass "$what"; else fail "$what"; fi
}

need_bin() {
  if [ ! -x "$BIN" ]; then
    echo "FAIL: $BIN not found (cargo build --release --bin irlgrid, or set IRLGRID_BIN)"
    exit 1
  fi
}

# Kills every process this script started (by pid), then runs EXTRA_CLEANUP.
cleanup() {
  local p
  for p in "${PIDS[@]}"; do
    kill -9 "$p" 2>/dev/null || true
  done
  for p in "${PIDS[@]}"; do
    wait "$p" 2>/dev/null || true
  done
  if declare -F extra_cleanup >/dev/null; then extra_cleanup || true; fi
  if [ -n "${WORK:-}" ] && [ "${KEEP_WORK:-0}" != 1 ]; then rm -rf "$WORK"; fi
}

# A fresh place for one coordinator: sets WORK (a new temporary directory
# named irlgrid-NAME.XXXXXX), PORT (free on loopback), URL, DB and CLOG.
# new_site NAME
new_site() {
  WORK="$(mktemp -d -t "irlgrid-$1.XXXXXX")"
  PORT="$($REL free-port)"
  URL="http://127.0.0.1:$PORT"
  DB="$WORK/grid.db"
  CLOG="$WORK/coordinator.log"
}

# Starts a coordinator in the background; sets COORD_PID. Appends its log.
# start_coordinator BIND DB LOG [extra args...]
start_coordinator() {
  local bind="$1" db="$2" logf="$3"; shift 3
  RUST_LOG="${COORD_LOG_LEVEL:-info}" IRLGRID_LOG_JSON=1 \
    "$BIN" coordinator --bind "$bind" --db "$db" "$@" >>"$logf" 2>&1 &
  COORD_PID=$!
  PIDS+=("$COORD_PID")
}

# Waits until GET /healthz answers 200 (limit in seconds).
wait_healthy() {
  local url="$1" limit="${2:-30}" t0=$SECONDS
  while [ $((SECONDS - t0)) -lt "$limit" ]; do
    case "$($REL healthz "$url" 2>/dev/null)" in 200*) return 0 ;; esac
    sleep 0.2
  done
  return 1
}

# Starts a worker; sets WPID. start_worker NAME URL SPOOL LOG [extra args]
start_worker() {
  local name="$1" url="$2" spool="$3" logf="$4"; shift 4
  RUST_LOG=info IRLGRID_LOG_JSON=1 \
    "$BIN" worker --coordinator "$url" --jobs 1 --name "$name" --spool-dir "$spool" "$@" \
    >>"$logf" 2>&1 &
  WPID=$!
  PIDS+=("$WPID")
}

rand_ms() { # rand_ms MIN_MS MAX_MS -> milliseconds
  echo $(($1 + (RANDOM * 32768 + RANDOM) % ($2 - $1 + 1)))
}
ms_to_s() { printf '%d.%03d\n' $(($1 / 1000)) $(($1 % 1000)); }
rand_between() { # rand_between MIN_MS MAX_MS -> seconds with 3 decimals
  ms_to_s "$(rand_ms "$1" "$2")"
}

alive() { kill -0 "$1" 2>/dev/null; }

finish() {
  if [ "$FAILED" = 0 ]; then
    echo "RESULT: PASS ${SCRIPT_NAME}"
  else
    echo "RESULT: FAIL ${SCRIPT_NAME}"
  fi
  exit "$FAILED"
}
