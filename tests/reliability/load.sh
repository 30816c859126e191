#!/usr/bin/env bash
# Load run: a coordinator process on loopback over a fresh
# database, and `coordinator/examples/load.rs` driving it with concurrent
# clients (lease, heartbeat, real-sized uploads, reads). Fails on any 5xx,
# transport error or unexpected status, and on a database inconsistency
# after the run.
#
# Env: LOAD_SECS (default 25; 60 with IRLGRID_RELIABILITY=full),
# LOAD_CLIENTS (200), LOAD_TOKEN (a bearer token for the coordinator;
# default: one is set), LOAD_JSON (write the figures there), LOAD_BIN (a
# built load generator), IRLGRID_BIN (a built irlgrid binary).
#
# LOAD_SCALE=1: the scale run instead: LOAD_WORKERS (1000) workers at a
# real worker's cadence (lease, a heartbeat every heartbeat_secs, one
# real-sized upload per job of LOAD_JOB_SECS, default 20:50 s) and
# LOAD_READERS (50) readers polling documents and dashboard pages, for
# LOAD_SECS (default 60).
#
# LOAD_PERF=FILE: also sample the coordinator's CPU with `perf record`
# (99 Hz, no call graph) for the length of the run into FILE; read it with
# `perf report -i FILE --sort comm` (by thread) or `--sort symbol`.
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/reliability/common.sh

if [ "${IRLGRID_RELIABILITY:-quick}" = full ] || [ -n "${LOAD_SCALE:-}" ]; then
  secs=${LOAD_SECS:-60}
else
  secs=${LOAD_SECS:-25}
fi
clients=${LOAD_CLIENTS:-200}
token=${LOAD_TOKEN-load-test-token-$$}

with_work_dir

need_release_binary
if [ -z "${LOAD_BIN:-}" ]; then
  echo "building the load generator"
  cargo build --release -q -p coordinator --example load
  LOAD_BIN=$TARGET_DIR/release/examples/load
fi

if [ -n "${LOAD_SCALE:-}" ]; then
  # A socket per simulated worker, on both ends.
  ulimit -n 65536 2>/dev/null || ulimit -n "$(ulimit -Hn)"
fi

port=$(free_port)
start_coordinator "$port" "$work/load.db" "$work/coordinator.log" "$token"
echo "coordinator pid $COORD_PID on 127.0.0.1:$port; $clients clients for $secs s"
args=(--url "http://127.0.0.1:$port" --secs "$secs" --clients "$clients"
      --pid "$COORD_PID" --db "$work/load.db" --stop)
if [ -n "${LOAD_SCALE:-}" ]; then
  args+=(--scale --workers "${LOAD_WORKERS:-1000}" --readers "${LOAD_READERS:-50}"
         --job-secs "${LOAD_JOB_SECS:-20:50}")
fi
[ -n "$token" ] && args+=(--token "$token")
[ -n "${LOAD_JSON:-}" ] && args+=(--json "$LOAD_JSON")
perf_pid=
if [ -n "${LOAD_PERF:-}" ]; then
  command -v perf >/dev/null || { echo "load: LOAD_PERF needs perf" >&2; exit 1; }
  perf record -q -F 99 -p "$COORD_PID" -o "$LOAD_PERF" 2>"$work/perf.log" &
  perf_pid=$!
fi
status=0
RUST_LOG=warn "$LOAD_BIN" "${args[@]}" || status=$?
if [ -n "$perf_pid" ]; then
  # perf stops when the coordinator exits (the generator stops it).
  wait "$perf_pid" 2>/dev/null || true
fi
wait "$COORD_PID" 2>/dev/null || true
COORD_PID=
if grep -E -n 'panicked|ERROR' "$work/coordinator.log" >&2; then
  echo "load: the coordinator logged errors or panics (above)" >&2
  status=1
fi
echo "database: $(du -h "$work/load.db" | cut -f1)"
exit "$status"
