#!/usr/bin/env bash
# CI step: the load run (tests/reliability/load.sh, ~25 s) and
# the API fuzzing (tests/reliability/fuzz_api.sh, a few minutes) against
# the release binary. IRLGRID_RELIABILITY=full runs both longer. Fuzzing
# prints SKIPPED when schemathesis cannot be installed; real findings fail.
set -euo pipefail
cd "$(dirname "$0")/../.."

t0=$SECONDS
bash tests/reliability/load.sh
echo "load: $((SECONDS - t0)) s"
t1=$SECONDS
bash tests/reliability/fuzz_api.sh
echo "fuzzing: $((SECONDS - t1)) s"
