#!/usr/bin/env python3
"""Independent reference for `irlgrid holdout` (leave-one-trial-out recovery).

Re-implements the trajectory analysis of docs/science.md (#preprocessing to
#paper-metrics) with SciPy (translate, rotate, scale to unit rise,
natural cubic spline over normalized chord length at 60 points, area
difference D) and holds out every trial of a grid of `irlgrid train` run
directories: its highest-return episode is scored against the weight means of
the other trials. Prints the area-metric confusion matrix (true w1 in rows,
inferred in columns), to compare with `irlgrid holdout --runs DIR`.

    pip install numpy scipy
    python3 tools/holdout_reference.py RUNS_DIR

Only converged trials with a sampling success rate of at least 0.5 count, as
in `irlgrid holdout`'s default.
"""
import glob
import json
import os
import sys

import numpy as np
from scipy.interpolate import CubicSpline


def resample(x, z):
    x = np.asarray(x, float) - x[0]
    z = np.asarray(z, float) - z[0]
    ang = np.arctan2(x[-1], z[-1])
    c, s = np.cos(ang), np.sin(ang)
    xr, zr = c * x - s * z, s * x + c * z
    xr, zr = xr / zr[-1], zr / zr[-1]
    keep = [0] + [i for i in range(1, len(xr)) if (xr[i], zr[i]) != (xr[i - 1], zr[i - 1])]
    xr, zr = xr[keep], zr[keep]
    d = np.r_[0, np.cumsum(np.hypot(np.diff(xr), np.diff(zr)))]
    u = np.linspace(0, 1, 60)
    return CubicSpline(d / d[-1], xr, bc_type="natural")(u)


def load(root):
    runs = []
    for path in sorted(glob.glob(os.path.join(root, "*", "samples.json"))):
        s = json.load(open(path))
        w1 = json.load(open(os.path.join(os.path.dirname(path), "summary.json")))["w1"]
        if not s["episodes"] or s["successes_found"] / max(s["attempts"], 1) < 0.5:
            continue
        xs = np.array([resample(e["com_x"], e["com_z"]) for e in s["episodes"]])
        top = int(np.argmax([e["return"] for e in s["episodes"]]))
        runs.append({"w1": w1, "mean": xs.mean(0), "top": xs[top]})
    return runs


def main(root):
    runs = load(root)
    grid = sorted({r["w1"] for r in runs})
    conf = np.zeros((len(grid), len(grid)), int)
    for r in runs:
        if sum(o["w1"] == r["w1"] for o in runs) < 2:
            continue
        d = []
        for w in grid:
            others = [o["mean"] for o in runs if o["w1"] == w and o is not r]
            d.append(np.abs(r["top"] - np.mean(others, 0)).sum())
        conf[grid.index(r["w1"]), int(np.argmin(d))] += 1
    n = conf.sum()
    within = sum(conf[i, j] for i in range(len(grid)) for j in range(len(grid)) if abs(i - j) <= 1)
    print(f"{n} cases; by area {np.trace(conf)} exact, {within} within one grid step")
    print("w1 grid:", grid)
    print(conf)


if __name__ == "__main__":
    main(sys.argv[1])
