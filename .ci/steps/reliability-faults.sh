#!/usr/bin/env bash
# CI step: the fault tests of tests/reliability/ (killed workers and
# coordinators, one killed between an output and its summary, network
# cuts, a full disk, hung workers) in quick mode,
# each bounded in time; IRLGRID_RELIABILITY=full runs the heavier mode.
# Reuses the release binary (built here when absent). Parts that need root
# or tools print SKIPPED instead of failing.
set -euo pipefail
cd "$(dirname "$0")/../.."

TARGET="${CARGO_TARGET_DIR:-target}"
export IRLGRID_BIN="${IRLGRID_BIN:-$TARGET/release/irlgrid}"
if [ ! -x "$IRLGRID_BIN" ]; then
  echo "building $IRLGRID_BIN"
  cargo build --release --bin irlgrid
fi
if ! command -v python3 >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3 >/dev/null
  else
    echo "SKIPPED: reliability fault tests (no python3 and cannot apt-get install it)"
    exit 0
  fi
fi
# `ip` (iproute2) lets netcut.sh use a network namespace; without it the
# TCP-proxy fallback runs instead.
if [ "$(id -u)" = 0 ] && ! command -v ip >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  echo "installing iproute2"
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq iproute2 >/dev/null || true
fi

if [ "${IRLGRID_RELIABILITY:-quick}" = full ]; then LIMIT=1800; else LIMIT=150; fi
status=0
summary=()
for t in chaos_workers kill_coordinator extend_crash summary_crash netcut disk_faults hung_worker soak; do
  echo "--- tests/reliability/$t.sh (limit ${LIMIT}s)"
  t0=$SECONDS
  out="$(mktemp)"
  if timeout --kill-after=10 "$LIMIT" bash "tests/reliability/$t.sh" 2>&1 | tee "$out"; then
    if grep -q '^SKIPPED' "$out"; then
      summary+=("$(grep -m1 '^SKIPPED' "$out")")
    else
      summary+=("PASS $t ($((SECONDS - t0))s)")
    fi
  else
    summary+=("FAIL $t ($((SECONDS - t0))s)")
    status=1
  fi
  rm -f "$out"
done
printf '%s\n' "${summary[@]}"
exit "$status"
