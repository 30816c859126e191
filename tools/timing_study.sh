#!/usr/bin/env bash
# Timing as evidence (docs/inference.md#observables): the posterior's
# identifiability with each observable set (shape, timing, relative
# timing and their combinations) on a finished solver study's stored
# outputs, with and without its optimizer variant, and the 3x-slowed
# subject check. Nothing is trained: every figure is `irlgrid holdout` /
# `irlgrid analyze` on the stored outputs.
#
#   bash tools/timing_study.sh STUDY_DIR [OUT_DIR]
#
# STUDY_DIR holds outputs.json (`python3 tools/lib/search_outputs.py
# study.db > outputs.json`, e.g. from tools/solver_study.sh). Writes to
# OUT_DIR (default STUDY_DIR/timing): holdout-all.{txt,json} (every
# variant), holdout-no-optimizer.{txt,json}, observables.tsv (one row per
# observable set and variant selection), per_value.tsv, slowed.tsv (the
# slowed subjects' answers) and the commands it ran (commands.txt).
set -euo pipefail
cd "$(dirname "$0")/.."
STUDY=${1:?usage: tools/timing_study.sh STUDY_DIR [OUT_DIR]}
OUT=${2:-$STUDY/timing}
BIN=${BIN:-target/release/irlgrid}
[ -x "$BIN" ] || cargo build --release --bin irlgrid
mkdir -p "$OUT"
: > "$OUT/commands.txt"
run() { echo "$*" >> "$OUT/commands.txt"; "$@"; }

python3 - "$STUDY/outputs.json" "$OUT/outputs-no-optimizer.json" <<'PY'
import json, sys
weights = json.load(open(sys.argv[1]))
for w in weights:
    w["trials"] = [t for t in w["trials"] if t.get("solver", {}).get("kind") != "optimizer"]
json.dump(weights, open(sys.argv[2], "w"))
PY

for sel in all no-optimizer; do
  src="$STUDY/outputs.json"
  [ "$sel" = no-optimizer ] && src="$OUT/outputs-no-optimizer.json"
  run "$BIN" holdout --outputs "$src" --out "$OUT/holdout-$sel.json" > "$OUT/holdout-$sel.txt"
done

# Subjects: each grid value's first PPO trial's best kept episode, as
# recorded and with its time axis slowed 3x (human-scale durations).
python3 - "$STUDY/outputs.json" "$OUT" <<'PY'
import json, sys
weights, out = json.load(open(sys.argv[1])), sys.argv[2]
with open(f"{out}/subjects.csv", "w") as f:
    f.write("subject,time,x,z\n")
    for w in weights:
        ppo = [t for t in w["trials"] if t.get("solver", {}).get("kind", "ppo") == "ppo"
               and t["converged"] and t["episodes"]]
        if not ppo:
            continue
        ep = max(ppo[0]["episodes"], key=lambda e: e["return"])
        for tag, k in (("1x", 1.0), ("3x", 3.0)):
            name = f"synthetic-w1-{w['params']['w1']}-{tag}"
            for t, x, z in zip(ep["com_t"], ep["com_x"], ep["com_z"]):
                f.write(f"{name},{k * t!r},{x!r},{z!r}\n")
PY
for obs in shape timing relative_timing shape+timing shape+relative_timing; do
  run "$BIN" analyze --outputs "$STUDY/outputs.json" --subjects "$OUT/subjects.csv" \
    --observables "$obs" --out "$OUT/analyze-$obs.json"
done

python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
def lv(c, p):
    return next(l for l in c["levels"] if round(l["level"] * 100) == p)
with open(f"{out}/observables.tsv", "w") as f, open(f"{out}/per_value.tsv", "w") as g:
    f.write("variants\tobservables\tcases\twithin_one\texact\tmin_value_within_one\tcov50\tcov80"
            "\tcov90\tcov95\tsize90\tgain_nats\tlovo_cov90_all\tlovo_cov90_by_variant\n")
    g.write("variants\tobservables\tw1\tcases\twithin_one\n")
    for sel in ("all", "no-optimizer"):
        h = json.load(open(f"{out}/holdout-{sel}.json"))
        for o in h.get("by_observables", []):
            c = o["coverage"]
            fr = [w / n for n, w in o["per_value"] if n]
            lovo = o.get("by_solver_overall")
            by = ",".join(f"{b['solver']}={lv(b['coverage'], 90)['coverage']:.3f}"
                          for b in o.get("by_solver", []))
            f.write("\t".join([sel, o["observables"], str(c["cases"]),
                               f"{o['within_one'] / c['cases']:.3f}", str(o["exact"]),
                               f"{min(fr):.3f}"]
                              + [f"{lv(c, p)['coverage']:.3f}" for p in (50, 80, 90, 95)]
                              + [f"{lv(c, 90)['mean_set_size']:.2f}", f"{c['gain_nats']:.3f}",
                                 f"{lv(lovo, 90)['coverage']:.3f}" if lovo else "", by]) + "\n")
            for v, (n, w) in zip(h["values"], o["per_value"]):
                g.write(f"{sel}\t{o['observables']}\t{v}\t{n}\t{w}\n")
with open(f"{out}/slowed.tsv", "w") as f:
    f.write("observables\tsubject\tmap\tcredible_set\tout_of_model\treason\n")
    for obs in ("shape", "timing", "relative_timing", "shape+timing", "shape+relative_timing"):
        doc = json.load(open(f"{out}/analyze-{obs}.json"))
        for s in doc["subjects"]:
            p = s["methods"]["posterior"]
            oom = p.get("out_of_model") or {}
            cs = p.get("credible_set") or {}
            f.write("\t".join([obs, s["subject"], str(p.get("inferred")),
                               ",".join(str(v) for v in cs.get("values", [])),
                               str(oom.get("flagged")), oom.get("reason") or ""]) + "\n")
print(open(f"{out}/observables.tsv").read())
PY
