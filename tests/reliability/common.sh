# Helpers for the reliability scripts (sourced): the release binary, free
# ports, starting and stopping a coordinator process.

TARGET_DIR=${CARGO_TARGET_DIR:-target}
IRLGRID_BIN=${IRLGRID_BIN:-$TARGET_DIR/release/irlgrid}

need_release_binary() {
  if [ ! -x "$IRLGRID_BIN" ]; then
    echo "building $IRLGRID_BIN"
    cargo build --release --bin irlgrid
  fi
}

free_port() {
  python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1]); s.close()'
}

# start_coordinator PORT DB LOG [TOKEN]: starts it in the background, sets
# COORD_PID, waits until /healthz answers.
start_coordinator() {
  local port=$1 db=$2 log=$3 token=${4:-}
  if [ -n "$token" ]; then
    IRLGRID_TOKEN=$token "$IRLGRID_BIN" coordinator --bind "127.0.0.1:$port" --db "$db" >"$log" 2>&1 &
  else
    env -u IRLGRID_TOKEN "$IRLGRID_BIN" coordinator --bind "127.0.0.1:$port" --db "$db" >"$log" 2>&1 &
  fi
  COORD_PID=$!
  for _ in $(seq 1 100); do
    if python3 -c "import urllib.request,sys; urllib.request.urlopen('http://127.0.0.1:$port/healthz', timeout=1)" 2>/dev/null; then
      return 0
    fi
    if ! kill -0 "$COORD_PID" 2>/dev/null; then
      echo "coordinator exited at start:" >&2
      cat "$log" >&2
      return 1
    fi
    sleep 0.1
  done
  echo "coordinator did not answer /healthz within 10 s" >&2
  return 1
}

# stop_coordinator: SIGTERM to COORD_PID (if still running) and wait.
stop_coordinator() {
  if [ -n "${COORD_PID:-}" ] && kill -0 "$COORD_PID" 2>/dev/null; then
    kill -TERM "$COORD_PID" 2>/dev/null || true
    wait "$COORD_PID" 2>/dev/null || true
  fi
  COORD_PID=
}

# with_work_dir: a temporary directory in $work; on exit the coordinator is
# stopped and the directory removed.
with_work_dir() {
  work=$(mktemp -d)
  COORD_PID=
  trap 'stop_coordinator; rm -rf "$work"' EXIT
}
