#!/usr/bin/env bash
# Chooses the posterior's summary size and pooling by measurement: runs
# `irlgrid holdout` over a finished grid for each (components, pooling)
# and prints the posterior's leave-one-trial-out coverage at 50/80/90/95 %,
# mean 90 % set size and log-score gain over uniform, one row per setting.
#
#   bash tools/posterior_sweep.sh RUNS_DIR [OUT.tsv]
#
# RUNS_DIR holds `irlgrid train` run directories (e.g. target/recovery/runs
# from tools/recovery.sh). Each holdout takes well under a second.
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:?usage: tools/posterior_sweep.sh RUNS_DIR [OUT.tsv]}
OUT=${2:-/dev/stdout}
BIN=${BIN:-target/release/irlgrid}
COMPONENTS=${COMPONENTS:-0 1 2 3 4}
POOLING=${POOLING:-0 2 4 8 16 32}
[ -x "$BIN" ] || cargo build --release --bin irlgrid
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
{
  printf 'components\tpooling\tcases\tcov50\tcov80\tcov90\tcov95\tsize90\tgain_nats\twithin_one\n'
  for c in $COMPONENTS; do
    for k in $POOLING; do
      "$BIN" holdout --runs "$RUNS" --posterior-components "$c" --posterior-pooling "$k" \
        --out "$tmp/h.json" >/dev/null
      python3 - "$tmp/h.json" "$c" "$k" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
cal = r["coverage"]["posterior"]
lv = {round(l["level"] * 100): l for l in cal["levels"]}
print("\t".join([sys.argv[2], sys.argv[3], str(cal["cases"])]
      + [f"{lv[p]['coverage']:.3f}" for p in (50, 80, 90, 95)]
      + [f"{lv[90]['mean_set_size']:.2f}", f"{cal['gain_nats']:.3f}",
         str(r["methods"]["posterior"]["within_one"])]))
PY
    done
  done
} > "$OUT"
