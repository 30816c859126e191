#!/usr/bin/env bash
# Fuzzes the coordinator's HTTP API against its own OpenAPI document with
# schemathesis, once without a token and once with IRLGRID_TOKEN
# set (the fuzzer then sends it, and checks that writes without it are
# refused). Checks: no 5xx, status codes, content types and response
# bodies as documented; the coordinator must not log a panic or an
# internal error, must still answer afterwards, and its database must pass
# the consistency check of the load generator.
#
# schemathesis comes from PyPI into a venv under $CARGO_TARGET_DIR; when
# it cannot be installed (no network) the script prints SKIPPED and
# succeeds. Env: FUZZ_EXAMPLES (per operation and phase; default 150, 1000
# with IRLGRID_RELIABILITY=full), FUZZ_SEED (default 1), FUZZ_REPORT_DIR
# (keep the JUnit reports there).
set -euo pipefail
cd "$(dirname "$0")/../.."
source tests/reliability/common.sh

SCHEMATHESIS_VERSION=4.32.5
if [ "${IRLGRID_RELIABILITY:-quick}" = full ]; then examples=${FUZZ_EXAMPLES:-1000}; else examples=${FUZZ_EXAMPLES:-150}; fi
seed=${FUZZ_SEED:-1}

with_work_dir

venv=$TARGET_DIR/reliability/venv
st=$venv/bin/schemathesis
if ! "$st" --version 2>/dev/null | grep -q "$SCHEMATHESIS_VERSION"; then
  echo "installing schemathesis $SCHEMATHESIS_VERSION into $venv"
  mkdir -p "$(dirname "$venv")"
  if ! { python3 -m venv "$venv" &&
         timeout 600 "$venv/bin/pip" install -q --disable-pip-version-check \
           "schemathesis==$SCHEMATHESIS_VERSION"; } >"$work/pip.log" 2>&1; then
    echo "SKIPPED: API fuzzing (pip could not install schemathesis: $(tail -1 "$work/pip.log"))"
    exit 0
  fi
fi

need_release_binary
if [ -z "${LOAD_BIN:-}" ]; then
  echo "building the database checker"
  cargo build --release -q -p coordinator --example load
  LOAD_BIN=$TARGET_DIR/release/examples/load
fi

# A search with queued jobs, so that lease requests answer at once rather
# than long-polling for their wait_secs.
seed_search() {
  local port=$1 token=$2
  python3 - "$port" "$token" <<'PY'
import json, sys, urllib.request
port, token = sys.argv[1], sys.argv[2]
body = {"name": "fuzz seed", "reward_grid": {"w1": [i * 0.5 + 0.5 for i in range(64)]}, "trials": 100,
        "sampling": {"successful_episodes": 2, "top_k": 2, "max_attempts": 10}}
req = urllib.request.Request(f"http://127.0.0.1:{port}/api/v1/searches", data=json.dumps(body).encode(),
                             headers={"Content-Type": "application/json"}, method="POST")
if token:
    req.add_header("Authorization", f"Bearer {token}")
print(urllib.request.urlopen(req, timeout=10).read().decode())
PY
}

failed=0
total_cases=0
fuzz() {
  local label=$1 token=$2
  local port db log out
  port=$(free_port)
  db=$work/$label.db
  log=$work/$label-coordinator.log
  out=$work/$label-schemathesis.txt
  start_coordinator "$port" "$db" "$log" "$token"
  seed_search "$port" "$token" >/dev/null
  local checks=not_a_server_error,status_code_conformance,content_type_conformance,response_schema_conformance,negative_data_rejection
  # With a token: also that the writes refuse requests without it.
  [ -n "$token" ] && checks+=",ignored_auth"
  local args=(run "http://127.0.0.1:$port/api/v1/openapi.json" --url "http://127.0.0.1:$port"
    --checks "$checks"
    --phases examples,coverage,fuzzing --max-examples "$examples" --seed "$seed"
    --workers 2 --request-timeout 40 --no-shrink --suppress-health-check all
    --report junit --report-dir "$work/$label-report")
  [ -n "$token" ] && args+=(-H "Authorization: Bearer $token")
  echo "== $label: schemathesis, $examples examples per operation and phase (seed $seed)"
  local rc=0
  local t0=$SECONDS
  NO_COLOR=1 "$st" "${args[@]}" >"$out" 2>&1 || rc=$?
  echo "   finished in $((SECONDS - t0)) s with exit code $rc"
  # The summary: operations, test cases, failures.
  grep -E -i '^(Operations|Test cases|Test Phases|Failures|Errors|Seed)|passed|failed|unique failures|skipped|warnings?:' "$out" | tail -n 12 | sed 's/^/   /' || true
  local n
  n=$(python3 - "$work/$label-report" <<'PY'
import glob, sys, xml.etree.ElementTree as ET
n = 0
for f in glob.glob(sys.argv[1] + "/*.xml"):
    for tc in ET.parse(f).getroot().iter("testcase"):
        n += 1
print(n)
PY
)
  local cases
  cases=$(grep -E -o '[0-9]+ generated' "$out" | head -1 | grep -E -o '[0-9]+' || echo "?")
  echo "   $n operations tested, test cases generated: $cases"
  [ "$cases" != "?" ] && total_cases=$((total_cases + cases))
  if [ "$rc" -ne 0 ]; then
    echo "   FAILURES ($label):"
    sed -n '/FAILURES/,$p' "$out" | head -n 150 | sed 's/^/   | /'
    failed=1
  fi
  if ! kill -0 "$COORD_PID" 2>/dev/null; then
    echo "   the coordinator died during fuzzing" >&2
    failed=1
  elif ! python3 -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:$port/healthz', timeout=5)"; then
    echo "   the coordinator stopped answering /healthz" >&2
    failed=1
  fi
  stop_coordinator
  if grep -E -n 'panicked|internal error' "$log" | head -n 20 | sed 's/^/   coordinator: /' | grep -q .; then
    grep -E -n 'panicked|internal error' "$log" | head -n 20 >&2
    echo "   the coordinator logged a panic or an internal error" >&2
    failed=1
  fi
  if ! "$LOAD_BIN" --check-only --db "$db" | sed 's/^/   /'; then
    failed=1
  fi
  if [ -n "${FUZZ_REPORT_DIR:-}" ]; then
    mkdir -p "$FUZZ_REPORT_DIR"
    cp "$out" "$FUZZ_REPORT_DIR/"
    cp -r "$work/$label-report" "$FUZZ_REPORT_DIR/" 2>/dev/null || true
  fi
}

fuzz open ""
fuzz token "fuzz-token-$$-$RANDOM"
echo "fuzzing: $total_cases test cases in all"
if [ "$failed" -ne 0 ]; then
  echo "fuzzing found problems (above)" >&2
  exit 1
fi
echo "fuzzing: no 5xx, no schema mismatch, no panic"
