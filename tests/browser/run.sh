#!/usr/bin/env bash
# Browser test of the dashboard: starts a coordinator (with a
# token, on a temporary database), seeds it with a finished tiny search
# through the REST API (tests/browser/seed.py: synthetic uploads, no
# training), opens `/` and `/searches/{id}` in headless Chromium, saves
# screenshots under target/browser/, and fails on any console error, any
# missing chart, or the token showing up in the coordinator's log.
#
#   bash tests/browser/run.sh            # builds target/debug/irlgrid first
#   IRLGRID_BIN=path/to/irlgrid bash tests/browser/run.sh
#   CHROMIUM=/usr/bin/chromium ...       # browser to use
#   SCREENSHOT=docs/img/dashboard.png ...  # also save the finished search's
#                                        # page, top part, there (the image
#                                        # the README shows)
#
# Needs chromium, python3 and curl; .ci/steps/browser.sh installs them.
set -euo pipefail
cd "$(dirname "$0")/../.."

target_dir=${CARGO_TARGET_DIR:-target}
out=$target_dir/browser
mkdir -p "$out"
out=$(cd "$out" && pwd)
chromium=${CHROMIUM:-$(command -v chromium || command -v chromium-browser || true)}
[ -n "$chromium" ] || { echo "FAIL: no chromium on PATH (set CHROMIUM)" >&2; exit 1; }

if [ -z "${IRLGRID_BIN:-}" ]; then
  # The test profile (optimized, in target/debug): after `cargo test` this
  # reuses what the tests built.
  echo "building irlgrid"
  cargo build --quiet --profile test --bin irlgrid
  IRLGRID_BIN=$target_dir/debug/irlgrid
fi
"$IRLGRID_BIN" coordinator --help >/dev/null 2>&1 ||
  { echo "FAIL: $IRLGRID_BIN has no 'coordinator' subcommand" >&2; exit 1; }

work=$(mktemp -d)
coord_pid=
cleanup() {
  if [ -n "$coord_pid" ]; then kill "$coord_pid" 2>/dev/null || true; wait "$coord_pid" 2>/dev/null || true; fi
  rm -rf "$work"
}
trap cleanup EXIT

fail() {
  echo "FAIL: $*" >&2
  if [ -f "$work/coordinator.log" ]; then
    echo "--- coordinator log (last 40 lines) ---" >&2
    tail -n 40 "$work/coordinator.log" >&2
  fi
  exit 1
}

port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
base=http://127.0.0.1:$port
token=browser-$RANDOM-$RANDOM-$RANDOM
# Debug logging on purpose: the HTTP trace spans must not record the
# `?token=` of a dashboard URL.
IRLGRID_TOKEN=$token RUST_LOG=debug \
  "$IRLGRID_BIN" coordinator --bind "127.0.0.1:$port" --db "$work/irlgrid.db" \
  >"$work/coordinator.log" 2>&1 &
coord_pid=$!
for _ in $(seq 1 100); do
  curl -fsS "$base/healthz" >/dev/null 2>&1 && break
  kill -0 "$coord_pid" 2>/dev/null || fail "the coordinator exited at start-up"
  sleep 0.1
done
curl -fsS "$base/healthz" >/dev/null || fail "coordinator not healthy at $base"

id=$(python3 tests/browser/seed.py "$base" "$token") || fail "seeding the search failed"
echo "seeded finished search $id"
status=$(curl -fsS -H "Authorization: Bearer $token" "$base/api/v1/searches/$id" | python3 -c 'import json,sys; print(json.load(sys.stdin)["status"])')
[ "$status" = completed ] || fail "seeded search is $status, not completed"

# Without the token a page sends the browser to the login form.
code=$(curl -s -o /dev/null -w '%{http_code} %{redirect_url}' "$base/searches/$id")
case "$code" in
  "303 $base/login?next="*) ;;
  *) fail "unauthenticated page answered '$code', not a redirect to /login" ;;
esac

# One Chromium run per page; each has a fresh profile, so each URL carries
# ?token=, which the dashboard swaps for a cookie and strips by redirect.
browse() { # NAME URL HEIGHT -> $out/NAME.png, $out/NAME.html, $work/NAME.log
  local name=$1 url=$2 height=$3 profile
  profile=$(mktemp -d -p "$work")
  timeout 90 "$chromium" --headless --no-sandbox --disable-gpu --disable-dev-shm-usage \
    --no-first-run --hide-scrollbars --user-data-dir="$profile" \
    --enable-logging=stderr --v=0 --virtual-time-budget=10000 \
    --window-size="1400,$height" --screenshot="$out/$name.png" "$url" \
    >"$work/$name.shot.log" 2>&1 || fail "chromium failed on $name (see below)"$'\n'"$(tail -n 20 "$work/$name.shot.log")"
  timeout 90 "$chromium" --headless --no-sandbox --disable-gpu --disable-dev-shm-usage \
    --no-first-run --user-data-dir="$profile" \
    --enable-logging=stderr --v=0 --virtual-time-budget=10000 \
    --dump-dom "$url" >"$out/$name.html" 2>"$work/$name.log" ||
    fail "chromium --dump-dom failed on $name"$'\n'"$(tail -n 20 "$work/$name.log")"
  [ -s "$out/$name.png" ] || fail "no screenshot of $name"
  # Every console message is logged as `...:INFO:CONSOLE:N] "text", source:
  # URL (line)` whatever its level (console.error too), CSP refusals and
  # failed loads included; the dashboard's script logs nothing, so any
  # console line is an error.
  local errors
  errors=$(cat "$work/$name.shot.log" "$work/$name.log" |
    grep -E ':CONSOLE[:(]|Uncaught|Refused to|Failed to load resource' || true)
  [ -z "$errors" ] || fail "console errors on $name:"$'\n'"$errors"
  echo "ok: $name ($out/$name.png)"
}

# A second search left running, so that the pages' refresh script runs
# (virtual time lets it tick a few times).
running_id=$(python3 tests/browser/seed.py --running "$base" "$token") || fail "seeding the running search failed"
echo "seeded running search $running_id"

browse index "$base/?token=$token" 900
grep -q "browser test (synthetic data)" "$out/index.html" || fail "the search is not listed on /"
grep -q 'badge b-completed' "$out/index.html" || fail "/ does not show the search as completed"

browse search "$base/searches/$id?token=$token" 6400
html=$out/search.html
grep -q 'id="inferred"' "$html" || fail "no inferred-w1 table"
grep -q '<th>90 % credible set</th>' "$html" || fail "no credible sets in the inferred-w1 table"
# A cookie jar for curl, filled the way a browser gets it.
curl -fsS -c "$work/jar" -o /dev/null "$base/?token=$token" || fail "?token= login with curl failed"
missing=()
for chart in learning-curves fig2-area-torque fig3-trajectories fig4-area-ranking \
             fig6-correlation-ranking posterior identifiability-confusion \
             identifiability-coverage subject-0 subject-1 subject-2; do
  # Each figure holds its inline <svg> right after the opening tag.
  grep -q "<figure data-chart=\"$chart\"><svg " "$html" || missing+=("$chart")
  curl -fsS -b "$work/jar" "$base/searches/$id/charts/$chart.svg" -o "$out/$chart.svg" ||
    missing+=("$chart.svg")
  python3 -c 'import sys, xml.dom.minidom as m; d = m.parse(sys.argv[1]); assert d.documentElement.tagName == "svg"' \
    "$out/$chart.svg" 2>/dev/null || missing+=("$chart.svg (not well-formed)")
done
[ ${#missing[@]} -eq 0 ] || fail "missing or broken charts: ${missing[*]}"
grep -q 'NaN' "$html" && fail "NaN on the search page"

if [ -n "${SCREENSHOT:-}" ]; then
  # The top of the finished search's page, as the README shows it.
  browse readme "$base/searches/$id?token=$token" 1500
  cp "$out/readme.png" "$SCREENSHOT"
  echo "ok: screenshot saved as $SCREENSHOT"
fi

browse running "$base/searches/$running_id?token=$token" 3000
html=$out/running.html
grep -q 'data-running="true"' "$html" || fail "the running search's page does not say it runs"
grep -q 'browser-worker-1' "$html" || fail "the running job's worker is not listed"
grep -q '<figure data-chart="learning-curves"><svg ' "$html" || fail "no learning curves on the running search's page"
grep -q '<figure data-chart="fig2-area-torque"><svg ' "$html" || fail "no partial Fig. 2 on the running search's page"

# The token must not be in the log, although every URL above carried it.
sed 's/\x1b\[[0-9;]*m//g' "$work/coordinator.log" >"$work/coordinator.plain.log"
grep -qF "$token" "$work/coordinator.plain.log" && fail "the token appears in the coordinator's log"
if grep -q 'path=/searches/' "$work/coordinator.plain.log"; then
  # The running page's script fetched its live part at least once.
  grep -q "path=/fragments/searches/$running_id/live" "$work/coordinator.plain.log" ||
    fail "the running search's page never refreshed its live part"
else
  echo "note: no debug request spans in the log (tracing set up differently?)"
fi

echo "browser test passed: screenshots and pages in $out"
