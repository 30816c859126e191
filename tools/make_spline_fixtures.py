#!/usr/bin/env python3
"""Generate the SciPy reference fixtures for the trajectory analysis
(docs/science.md#preprocessing, docs/science.md#resampling).

Writes, relative to the repository root:
  shared/tests/fixtures/spline_natural.json  natural cubic splines:
      [{name, t, y, t_eval, y_eval}], y_eval = CubicSpline(t, y,
      bc_type="natural")(t_eval), t_eval reaching slightly past both ends.
  shared/tests/fixtures/resample_path.json   the full resampling pipeline:
      [{name, x, z, out_x, out_z, area}], computed here independently of the
      Rust code (angle-based rotation, numpy chord lengths, SciPy splines).

The Rust tests read these with include_str! and compare to 1e-9; Python never
runs in `cargo test`. Deterministic (fixed seed), so re-running reproduces the
files. Needs numpy and scipy:  pip install numpy scipy
Run from anywhere:  python3 tools/make_spline_fixtures.py
"""

import json
import pathlib

import numpy as np
from scipy.interpolate import CubicSpline

ROOT = pathlib.Path(__file__).resolve().parent.parent
OUT = ROOT / "shared" / "tests" / "fixtures"
RESAMPLE_POINTS = 60

rng = np.random.default_rng(20240611)


def spline_case(name, t, y, n_eval=120):
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    span = min(t[-1] - t[0], 1.0)
    t_eval = np.concatenate(
        [
            np.linspace(t[0] - 0.05 * span, t[-1] + 0.05 * span, n_eval),
            t,  # the knots themselves
        ]
    )
    y_eval = CubicSpline(t, y, bc_type="natural")(t_eval)
    return {
        "name": name,
        "t": t.tolist(),
        "y": y.tolist(),
        "t_eval": t_eval.tolist(),
        "y_eval": y_eval.tolist(),
    }


def spline_cases():
    cases = []
    t = np.sort(rng.uniform(0.0, 1.0, 8))
    cases.append(spline_case("random_8_knots", t, rng.normal(size=8)))
    # Uneven spacing: neighbouring gaps differ up to ~100-fold. (Far wilder
    # ratios make the interpolant itself swing to 1e3 and beyond, so an
    # absolute 1e-9 comparison would test f64 rounding, not the algorithm.)
    gaps = rng.choice([0.01, 0.05, 0.3, 1.0], size=14) * rng.uniform(0.5, 1.5, 14)
    t = np.concatenate([[-1.0], -1.0 + np.cumsum(gaps)])
    cases.append(spline_case("uneven_15_knots", t, rng.normal(size=15) * 3.0))
    cases.append(spline_case("three_knots", [0.0, 0.4, 1.0], [1.0, -0.5, 2.0]))
    t = np.sort(rng.uniform(0.0, 1.0, 60))
    t[0], t[-1] = 0.0, 1.0
    y = np.sin(7.0 * t) + 0.05 * rng.normal(size=60)
    cases.append(spline_case("smooth_noisy_60_knots", t, y, n_eval=300))
    return cases


def pipeline(x, z):
    """Preprocessing and resampling (docs/science.md#preprocessing), written independently."""
    x = np.asarray(x, dtype=float)
    z = np.asarray(z, dtype=float)
    # Drop exact consecutive repeats (zero chords), as the Rust code documents.
    keep = [0] + [i for i in range(1, len(x)) if x[i] != x[i - 1] or z[i] != z[i - 1]]
    x, z = x[keep], z[keep]
    x = x - x[0]
    z = z - z[0]
    a = np.arctan2(x[-1], z[-1])  # end direction, angle from vertical
    rise = np.hypot(x[-1], z[-1])
    xr = (np.cos(a) * x - np.sin(a) * z) / rise
    zr = (np.sin(a) * x + np.cos(a) * z) / rise
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xr), np.diff(zr)))])
    u = s / s[-1]
    uu = np.linspace(0.0, 1.0, RESAMPLE_POINTS)
    out_x = CubicSpline(u, xr, bc_type="natural")(uu)
    out_z = CubicSpline(u, zr, bc_type="natural")(uu)
    area = float(np.sum(0.5 * (out_x[1:] + out_x[:-1]) * np.diff(out_z)))
    return out_x, out_z, area


def transform(x, z, angle, scale, dx, dz):
    c, s = np.cos(angle), np.sin(angle)
    return scale * (c * x - s * z) + dx, scale * (s * x + c * z) + dz


def squat_like(n=160, noise=2e-4):
    """A COM path like a squat-to-stand at 200 Hz: smooth time profile, so
    the spatial spacing is uneven (dense at start and end)."""
    tau = np.linspace(0.0, 1.0, n)
    s = tau * tau * (3.0 - 2.0 * tau)
    x = 0.04 + 0.06 * np.sin(np.pi * s) - 0.03 * s + noise * rng.normal(size=n)
    z = 0.60 + 0.38 * s + noise * rng.normal(size=n)
    return x, z


def path_cases():
    cases = []

    def add(name, x, z):
        out_x, out_z, area = pipeline(x, z)
        cases.append(
            {
                "name": name,
                "x": np.asarray(x, dtype=float).tolist(),
                "z": np.asarray(z, dtype=float).tolist(),
                "out_x": out_x.tolist(),
                "out_z": out_z.tolist(),
                "area": area,
            }
        )

    x, z = squat_like()
    add("squat_like_200hz", x, z)
    xt, zt = transform(x, z, 0.7, 3.5, -2.0, 10.0)
    add("squat_like_rotated_scaled", xt, zt)
    s = np.linspace(0.0, 1.0, 25) ** 1.5
    add("backward_bulge_tilted", -0.3 * np.sin(np.pi * s) + 0.2 * s, 1.3 * s)
    s = np.linspace(0.0, 1.0, 40)
    add("s_shape", 0.1 * np.sin(2.0 * np.pi * s), 2.0 * s + 0.1 * s * s)
    add("sparse_6_points", [0.0, 0.05, 0.11, 0.1, 0.06, 0.02], [0.0, 0.2, 0.45, 0.7, 0.9, 1.1])
    # A recorder that idles at the start and end: exact repeats.
    x, z = squat_like(n=60, noise=0.0)
    xd = np.concatenate([[x[0]] * 5, x, [x[-1]] * 4])
    zd = np.concatenate([[z[0]] * 5, z, [z[-1]] * 4])
    xd = np.insert(xd, 30, xd[30])
    zd = np.insert(zd, 30, zd[30])
    add("idle_repeats", xd, zd)
    return cases


def main():
    OUT.mkdir(parents=True, exist_ok=True)
    for name, cases in [
        ("spline_natural.json", spline_cases()),
        ("resample_path.json", path_cases()),
    ]:
        path = OUT / name
        path.write_text(json.dumps(cases, indent=1) + "\n")
        print(f"wrote {path} ({len(cases)} cases)")


if __name__ == "__main__":
    main()
