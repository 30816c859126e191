"""How much does the path's shape cost in return? Per w1 of one reward study
directory (tools/reward_study.sh): every trial's path area (from
`irlgrid analyze`, analysis.json) beside the mean return of its kept (best)
episodes, their spreads, and the least-squares slope of return on area with
its standard error. Where the optimizer's answer exists (optimum.json), its
area and return are printed too.

A reward identifies w1 by path shape only if shape costs return: if trials
whose best returns agree to a fraction of a percent draw paths whose areas
spread as widely as the grid's weight means, the area a solver lands on is
the solver's, not the reward's (docs/reward-study.md, "The price of shape").

    python3 tools/shape_price.py target/reward-study/power
"""
import json
import math
import pathlib
import statistics as st
import sys

sys.path.insert(0, str(pathlib.Path(__file__).parent / "lib"))
from study import optima, used_trial_areas  # noqa: E402

out = pathlib.Path(sys.argv[1])
best_return = {}
for d in sorted((out / "runs").iterdir()):
    if not (d / "samples.json").exists():
        continue
    s = json.loads((d / "summary.json").read_text())
    eps = json.loads((d / "samples.json").read_text())["episodes"]
    if eps:
        best_return[(s["w1"], s["seed"])] = st.mean(e["return"] for e in eps)

opt = optima(out)

cols = ["w1", "trials", "area_min", "area_max", "area_sd", "return_min", "return_max",
        "return_spread_pct", "slope_return_per_0.01_area", "slope_se", "opt_area", "opt_return"]
print("\t".join(cols))
for w in json.loads((out / "analysis.json").read_text())["weights"]:
    pairs = [(area, best_return[(w["value"], seed)])
             for seed, area in used_trial_areas(w)
             if (w["value"], seed) in best_return]
    if len(pairs) < 3:
        continue
    a = [p[0] for p in pairs]
    r = [p[1] for p in pairs]
    ma, mr = st.mean(a), st.mean(r)
    sxx = sum((x - ma) ** 2 for x in a)
    slope = sum((x - ma) * (y - mr) for x, y in pairs) / sxx
    resid = sum((y - mr - slope * (x - ma)) ** 2 for x, y in pairs)
    se = math.sqrt(resid / (len(pairs) - 2) / sxx)
    o = opt.get(w["value"])
    print("\t".join(str(x) for x in [
        w["value"], len(pairs), f"{min(a):.4f}", f"{max(a):.4f}", f"{st.stdev(a):.4f}",
        f"{min(r):.1f}", f"{max(r):.1f}", f"{100 * (max(r) - min(r)) / abs(mr):.2f}",
        f"{slope * 0.01:.2f}", f"{se * 0.01:.2f}",
        f"{o['area']:.4f}" if o and o.get("area") is not None else "-",
        f"{o['best']['return']:.1f}" if o else "-"]))
