"""Tables one reward study directory (tools/reward_study.sh): per w1, the
converged trials, PPO's stand-up duration, torque usage and path area of each
trial's kept (best) episodes, the mean and SD across trials of the trials'
path areas (from `irlgrid analyze`), the optimizer's duration, area and return, PPO's
optimality gap, and held-out recovery within one grid step per method.

    python3 tools/reward_table.py target/reward-study/power
"""
import json
import pathlib
import statistics as st
import sys

sys.path.insert(0, str(pathlib.Path(__file__).parent / "lib"))
from study import optima, used_trial_areas  # noqa: E402

out = pathlib.Path(sys.argv[1])
runs = {}
for d in sorted((out / "runs").iterdir()):
    s = json.loads((d / "summary.json").read_text())
    eps = json.loads((d / "samples.json").read_text())["episodes"] if (d / "samples.json").exists() else []
    runs.setdefault(s["w1"], []).append((s, eps))

opt = optima(out)

# PPO's path area per w1 across trials: the weight mean and the SD between
# the trials behind it; recovery by area needs neighbouring means to differ
# by more than that SD.
area = {}
if (out / "analysis.json").exists():
    for w in json.loads((out / "analysis.json").read_text())["weights"]:
        a = [v for _, v in used_trial_areas(w)]
        if w.get("area_mean") is not None:
            area[w["value"]] = (w["area_mean"], st.stdev(a) if len(a) > 1 else float("nan"))

hold = json.loads((out / "holdout.json").read_text()) if (out / "holdout.json").exists() else None
per_value = {}
if hold:
    for row in hold["per_value"]:
        per_value[row["value"]] = {m: (k, row["cases"]) for m, k in row["within_one"].items()}


cols = ["w1", "trials", "converged", "ppo_steps", "ppo_torque", "ppo_best_return",
        "ppo_area", "ppo_area_sd", "opt_steps", "opt_return", "opt_area", "gap_pct", "area_within1", "corr_within1", "post_within1"]
print("\t".join(cols))
for w in sorted(runs):
    rs = runs[w]
    conv = sum(s["final_success_rate"] >= 0.5 for s, _ in rs)
    steps = st.mean(st.mean(e["steps"] for e in eps) for _, eps in rs if eps) if any(eps for _, eps in rs) else float("nan")
    torque = st.mean(st.mean(e["torque_usage"] for e in eps) for _, eps in rs if eps) if any(eps for _, eps in rs) else float("nan")
    best = st.mean(st.mean(e["return"] for e in eps) for _, eps in rs if eps) if any(eps for _, eps in rs) else float("nan")
    o = opt.get(w)
    ob = o["best"] if o else None
    gap = 100 * (ob["return"] - best) / abs(ob["return"]) if ob else float("nan")
    pv = per_value.get(w, {})
    rec = lambda m: f"{pv[m][0]}/{pv[m][1]}" if m in pv else "-"
    print("\t".join(str(x) for x in [
        w, len(rs), conv, f"{steps:.1f}", f"{torque:.1f}", f"{best:.1f}",
        f"{area[w][0]:.4f}" if w in area else "-", f"{area[w][1]:.4f}" if w in area else "-",
        ob["steps"] if ob else "-", f"{ob['return']:.1f}" if ob else "-",
        f"{o['area']:.4f}" if o and o.get("area") is not None else "-",
        f"{gap:.2f}", rec("area"), rec("correlation"), rec("posterior")]))
