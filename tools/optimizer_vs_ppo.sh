#!/usr/bin/env bash
# The trajectory optimizer against PPO's best episodes, per w1 of a preset's
# grid (docs/reward-study.md#the-optimizer-under-power): the optimizer's
# return (noise-free squat) should reach the best PPO episode's return at
# every value.
#
#   PRESET=power nice -n 10 bash tools/optimizer_vs_ppo.sh PPO_DB [OUT_DIR]
#
# PPO_DB is a finished (or running) search's SQLite database with PPO jobs at
# the same grid, e.g. one of tools/solver_study.sh: the PPO reference at a
# w1 is the highest return of any kept episode of any PPO job there (every
# PPO variant). A `.json` file in place of the database is taken as that
# reference itself (an earlier run's OUT_DIR/ppo-reference.json). Each w1 is then solved as a search's optimizer job solves
# it: `irlgrid optimize --w1 X --threads 1 --seed SEED` (its one value,
# from the w1 = 0 optimum, on one core), timed. With LADDER=1 the whole grid
# is also solved in one call (continuation from the lowest value up).
# Environment (defaults in brackets): PRESET [power], GRID [the preset's],
# SEED [0], OPT_ARGS [] (extra `irlgrid optimize` flags, e.g.
# `--stretch-rounds 0` for the optimizer before stretching), LADDER [0],
# BIN [target/release/irlgrid]. Writes OUT_DIR/w1-X.json per value and the
# raw table OUT_DIR/optimizer-vs-ppo.tsv, a line per value as it finishes.
set -euo pipefail
cd "$(dirname "$0")/.."
DB=${1:?usage: optimizer_vs_ppo.sh PPO_DB [OUT_DIR]}
PRESET=${PRESET:-power}
OUT=${2:-target/optimizer-vs-ppo/$PRESET}
BIN=${BIN:-target/release/irlgrid}
SEED=${SEED:-0}
[ -x "$BIN" ] || cargo build --release --bin irlgrid
GRID=${GRID:-$("$BIN" presets | python3 -c "import json,sys; print(','.join(str(v) for p in json.load(sys.stdin) if p['name']=='$PRESET' for v in p['w1_grid']))")}
[ -n "$GRID" ] || { echo "unknown preset $PRESET" >&2; exit 2; }
mkdir -p "$OUT"

# The PPO reference per w1: {w1: [best episode return, jobs read]}.
if [[ $DB == *.json ]]; then
  [ "$(realpath "$DB")" = "$(realpath -m "$OUT/ppo-reference.json")" ] || cp "$DB" "$OUT/ppo-reference.json"
else
python3 - "$DB" > "$OUT/ppo-reference.json" <<'PY'
import json, sqlite3, sys
con = sqlite3.connect(f"file:{sys.argv[1]}?mode=ro", uri=True)
sid, config = con.execute("select id, config from searches order by seq desc limit 1").fetchone()
kinds = [s["kind"] for s in json.loads(config).get("solvers", [])] or ["ppo"]
best = {}
for params, variant, output in con.execute(
        "select p.params, j.variant, r.output from jobs j join job_results r on r.job_id = j.id"
        " join points p on p.search_id = j.search_id and p.idx = j.point_idx where j.search_id = ?",
        (sid,)):
    if kinds[variant] != "ppo":
        continue
    w1 = json.loads(params)["w1"]
    rets = [e["return"] for e in json.loads(output)["episodes"]]
    b = best.setdefault(str(w1), [float("-inf"), 0])
    b[0] = max([b[0]] + rets)
    b[1] += 1
json.dump(best, sys.stdout)
PY
fi

TABLE="$OUT/optimizer-vs-ppo.tsv"
printf 'w1\tppo_best_episode\tppo_jobs\toptimizer_return\toptimizer_steps\toutcome\tgap_pct\tjob_cpu_secs\n' > "$TABLE"
for W in ${GRID//,/ }; do
  # shellcheck disable=SC2086
  /usr/bin/time -f '%U %S' -o "$OUT/w1-$W.time" \
    "$BIN" optimize --preset "$PRESET" --w1 "$W" --threads 1 --seed "$SEED" ${OPT_ARGS:-} \
    --out "$OUT/w1-$W.json" > "$OUT/w1-$W.txt"
  python3 - "$OUT" "$W" >> "$TABLE" <<'PY'
import json, sys
out, w = sys.argv[1], sys.argv[2]
ref = json.load(open(f"{out}/ppo-reference.json"))
p = next((v for k, v in ref.items() if abs(float(k) - float(w)) < 1e-9), None)
o = json.load(open(f"{out}/w1-{w}.json"))["best"]
user, sys_ = open(f"{out}/w1-{w}.time").read().split()[-2:]
gap = f"{100 * (p[0] - o['return']) / abs(p[0]):.3f}" if p else ""
print("\t".join([w, f"{p[0]:.2f}" if p else "", str(p[1]) if p else "0", f"{o['return']:.2f}",
                 str(o["steps"]), o["outcome"], gap, f"{float(user) + float(sys_):.1f}"]))
PY
  tail -n 1 "$TABLE"
done
if [ "${LADDER:-0}" = 1 ]; then
  # shellcheck disable=SC2086
  "$BIN" optimize --preset "$PRESET" --w1 "$GRID" --seed "$SEED" ${OPT_ARGS:-} --out "$OUT/ladder.json" | tee "$OUT/ladder.txt"
fi
