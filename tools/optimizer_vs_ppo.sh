#!/usr/bin/env bash
# The trajectory optimizer against PPO's best episodes, per w1 of a preset's
# grid (docs/reward-study.md#the-optimizer-under-power). The optimizer's
# return (noise-free squat) should reach the best PPO episode's return at
# every value.
#
#   PRESET=power bash tools/optimizer_vs_ppo.sh REF_RESULT_JSON [OUT_DIR]
#
# REF_RESULT_JSON is a finished search's result document with PPO variants
# at the same grid (e.g. tools/solver_study.sh's result.json): the PPO
# reference at a w1 is the highest best-episode return (`best_return_max`)
# of any PPO variant there, and its optimizer column (if any) is the
# optimizer that search ran. This script then solves each w1 twice:
#   - ladder: one `irlgrid optimize --w1 GRID` call (continuation from the
#     lowest value up), as a user runs it;
#   - job: a search with only an optimizer variant, one job per w1 and
#     TRIALS jobs each (`irlgrid run`), as a search's solver variant runs
#     it, with each job's run time.
# Environment (defaults in brackets): PRESET [power], GRID [the preset's],
# TRIALS [1], WORKERS [1], OPTIMIZER [{}] (the variant's optimizer settings,
# JSON), OPT_ARGS [] (extra `irlgrid optimize` flags), SKIP_LADDER [0],
# SKIP_JOBS [0], BIN. Writes OUT_DIR/ladder.json, OUT_DIR/jobs/ (request,
# result, database) and the raw table OUT_DIR/optimizer-vs-ppo.tsv.
set -euo pipefail
cd "$(dirname "$0")/.."
REF=${1:?usage: optimizer_vs_ppo.sh REF_RESULT_JSON [OUT_DIR]}
PRESET=${PRESET:-power}
OUT=${2:-target/optimizer-vs-ppo/$PRESET}
BIN=${BIN:-target/release/irlgrid}
[ -x "$BIN" ] || cargo build --release --bin irlgrid
GRID=${GRID:-$("$BIN" presets | python3 -c "import json,sys; print(','.join(str(v) for p in json.load(sys.stdin) if p['name']=='$PRESET' for v in p['w1_grid']))")}
[ -n "$GRID" ] || { echo "unknown preset $PRESET" >&2; exit 2; }
TRIALS=${TRIALS:-1}
WORKERS=${WORKERS:-1}
OPTIMIZER=${OPTIMIZER:-{\}}
mkdir -p "$OUT/jobs"

if [ "${SKIP_LADDER:-0}" != 1 ]; then
  echo "==> ladder: irlgrid optimize --preset $PRESET --w1 $GRID ${OPT_ARGS:-}"
  start=$(date +%s.%N)
  # shellcheck disable=SC2086
  "$BIN" optimize --preset "$PRESET" --w1 "$GRID" ${OPT_ARGS:-} --out "$OUT/ladder.json" | tee "$OUT/ladder.txt"
  python3 -c "import sys; print(float(sys.argv[2]) - float(sys.argv[1]))" "$start" "$(date +%s.%N)" > "$OUT/ladder.secs"
fi

if [ "${SKIP_JOBS:-0}" != 1 ]; then
  echo "==> jobs: one optimizer variant, $TRIALS job(s) per w1, $WORKERS worker(s)"
  cat > "$OUT/jobs/request.json" <<JSON
{
  "name": "optimizer vs PPO: $PRESET",
  "reward_preset": "$PRESET",
  "reward_grid": {"w1": [$GRID]},
  "trials": $TRIALS,
  "seed": 1001,
  "solvers": [{"name": "optimizer", "kind": "optimizer", "optimizer": $OPTIMIZER}]
}
JSON
  rm -f "$OUT/jobs/study.db" "$OUT/jobs/study.db-wal" "$OUT/jobs/study.db-shm"
  "$BIN" run "$OUT/jobs/request.json" --exit --bind 127.0.0.1:0 --db "$OUT/jobs/study.db" \
    --workers "$WORKERS" --out "$OUT/jobs/result.json" 2>"$OUT/jobs/run.log" > "$OUT/jobs/summary.txt"
fi

python3 - "$REF" "$OUT" "$GRID" <<'PY'
import json, os, sqlite3, sys
ref_path, out, grid = sys.argv[1], sys.argv[2], [float(v) for v in sys.argv[3].split(",")]

def near(a, b):
    return abs(a - b) <= 1e-9 * max(1.0, abs(a))

ref = json.load(open(ref_path))
ppo, ref_opt = {}, {}
for w in ref["weights"]:
    best = None
    for s in w.get("solvers", []):
        if s["solver"]["kind"] == "ppo" and s.get("best_return_max") is not None:
            if best is None or s["best_return_max"] > best[0]:
                best = (s["best_return_max"], s["solver"]["name"])
    if best:
        ppo[w["value"]] = best
    if w.get("optimum"):
        ref_opt[w["value"]] = w["optimum"]["best_return"]

ladder = {}
if os.path.exists(f"{out}/ladder.json"):
    doc = json.load(open(f"{out}/ladder.json"))
    for o in doc if isinstance(doc, list) else [doc]:
        ladder[o["env"]["reward"]["w1"]] = (o["best"]["return"], o["best"]["steps"], o["best"]["outcome"])

jobs = {}
db = f"{out}/jobs/study.db"
if os.path.exists(db):
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    for params, output in con.execute(
            "select p.params, r.output from jobs j join job_results r on r.job_id = j.id"
            " join points p on p.search_id = j.search_id and p.idx = j.point_idx"):
        w1, o = json.loads(params)["w1"], json.loads(output)
        ret = max((e["return"] for e in o["episodes"]), default=float("nan"))
        steps = max((e["steps"] for e in o["episodes"]), default=0)
        jobs.setdefault(w1, []).append((ret, steps, o["train_secs"]))

def lookup(d, w):
    return next((v for k, v in d.items() if near(k, w)), None)

def gap(p, o):
    return f"{100.0 * (p - o) / abs(p):.3f}" if p is not None and o is not None and o == o else ""

rows = ["w1\tppo_best\tppo_variant\tref_optimizer\tladder_return\tladder_steps\tladder_gap_pct"
        "\tjob_return\tjob_steps\tjob_gap_pct\tjob_secs"]
for w in grid:
    p = lookup(ppo, w)
    pr = p[0] if p else None
    lad = lookup(ladder, w)
    js = lookup(jobs, w) or []
    jbest = max(js, default=None)
    rows.append("\t".join([
        f"{w:g}", f"{pr:.2f}" if pr is not None else "", p[1] if p else "",
        f"{lookup(ref_opt, w):.2f}" if lookup(ref_opt, w) is not None else "",
        f"{lad[0]:.2f}" if lad else "", str(lad[1]) if lad else "",
        gap(pr, lad[0]) if lad else "",
        f"{jbest[0]:.2f}" if jbest else "", str(jbest[1]) if jbest else "",
        gap(pr, jbest[0]) if jbest else "",
        ",".join(f"{j[2]:.1f}" for j in js)]))
text = "\n".join(rows) + "\n"
open(f"{out}/optimizer-vs-ppo.tsv", "w").write(text)
print(text, end="")
PY
