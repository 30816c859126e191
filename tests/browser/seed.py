#!/usr/bin/env python3
"""Seeds a running coordinator with one finished tiny search through its
REST API, acting as a worker that uploads synthetic results (no training):
a 3-point w1 grid x 2 trials, clearly synthetic subjects with planted w1
values, heartbeats with learning-curve progress, and one unconverged trial.

Usage: seed.py BASE_URL [TOKEN]            -> prints the finished search's id
       seed.py --running BASE_URL [TOKEN]  -> a second search left running: one
                                             job leased with heartbeats, one done,
                                             the rest queued; prints its id
Standard library only.
"""

import json
import math
import sys
import urllib.error
import urllib.request

GRID = [0.1, 1.0, 10.0]
TRIALS = 2
KEPT = 3  # successful_episodes = top_k = 3 for this tiny search


def call(base, token, method, path, body=None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + path, data=data, method=method)
    req.add_header("Content-Type", "application/json")
    if token:
        req.add_header("Authorization", "Bearer " + token)
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            text = r.read().decode()
            return r.status, (json.loads(text) if text else None)
    except urllib.error.HTTPError as e:
        raise SystemExit(f"{method} {path}: HTTP {e.code}: {e.read().decode()}")


def bulge(w1):
    return 0.05 + 0.08 * math.log(1.0 + w1)


def path(b, n):
    t, x, z = [], [], []
    for k in range(n):
        s = k / (n - 1)
        t.append(2.0 * s)
        x.append(b * math.sin(math.pi * s) + 0.02 * s * s)
        z.append(0.55 + 0.45 * s)
    return t, x, z


def subjects_csv():
    lines = ["subject,time,x,z"]
    for i, w1 in enumerate(GRID):
        t, x, z = path(bulge(w1) * 1.01, 50)
        for row in zip(t, x, z):
            lines.append(f"synthetic-s{i}-w1-{w1:g}," + ",".join(f"{v:.6f}" for v in row))
    return "\n".join(lines) + "\n"


def episodes(w1, trial):
    out = []
    for e in range(KEPT):
        t, x, z = path(bulge(w1) * (1.0 + 0.12 * trial + 0.01 * e), 40)
        out.append({
            "com_t": t, "com_x": x, "com_z": z,
            "return": 100.0 - trial - e,
            "torque_usage": 20.0 + 3.0 * w1 + trial,
            "steps": 40,
        })
    return out


def lease(base, token, worker):
    status, got = call(base, token, "POST", "/api/v1/leases", {"worker": worker, "wait_secs": 0})
    return None if status == 204 else got


def heartbeat(base, token, job, lt, w1, steps=4):
    progress = [{
        "env_steps": 500 * k, "total_env_steps": 2000,
        "mean_return": 5.0 + 10.0 * k + w1, "success_rate": min(1.0, 0.22 * k),
    } for k in range(1, steps + 1)]
    call(base, token, "POST", f"/api/v1/jobs/{job}/heartbeat",
         {"lease_token": lt, "phase": "training", "progress": progress})


def upload(base, token, job, lt, w1, trial, rate):
    call(base, token, "POST", f"/api/v1/jobs/{job}/result", {"lease_token": lt, "output": {
        "final_success_rate": rate, "env_steps": 2000,
        "successes_found": KEPT, "successes_wanted": KEPT, "sampling_attempts": KEPT + 1,
        "episodes": episodes(w1, trial), "train_secs": 1.0, "sample_secs": 0.1,
    }})


def running(base, token):
    """A search with one job done and one running; nothing else leases."""
    _, created = call(base, token, "POST", "/api/v1/searches", {
        "name": "browser test, running (synthetic data)",
        "reward_grid": {"w1": GRID},
        "trials": TRIALS,
        "seed": 2,
        "sampling": {"successful_episodes": KEPT, "top_k": KEPT},
        "subjects_csv": subjects_csv(),
    })
    for k in range(2):
        got = lease(base, token, f"browser-worker-{k}")
        if got is None:
            raise SystemExit("no job to lease for the running search")
        spec = got["spec"]
        heartbeat(base, token, got["job_id"], got["lease_token"], spec["params"]["w1"], steps=2 + k)
        if k == 0:
            upload(base, token, got["job_id"], got["lease_token"], spec["params"]["w1"], spec["trial"], 0.9)
    print(created["id"])


def main():
    if sys.argv[1] == "--running":
        base = sys.argv[2].rstrip("/")
        running(base, sys.argv[3] if len(sys.argv) > 3 else "")
        return
    base = sys.argv[1].rstrip("/")
    token = sys.argv[2] if len(sys.argv) > 2 else ""
    status, created = call(base, token, "POST", "/api/v1/searches", {
        "name": "browser test (synthetic data)",
        "reward_grid": {"w1": GRID},
        "trials": TRIALS,
        "seed": 1,
        "sampling": {"successful_episodes": KEPT, "top_k": KEPT},
        "subjects_csv": subjects_csv(),
    })
    assert status == 201, status
    sid = created["id"]
    n = 0
    while True:
        got = lease(base, token, "browser-seed")
        if got is None:
            break
        job, lt, spec = got["job_id"], got["lease_token"], got["spec"]
        w1, trial = spec["params"]["w1"], spec["trial"]
        heartbeat(base, token, job, lt, w1)
        rate = 0.2 if n == 4 else 0.9  # one trial does not converge
        upload(base, token, job, lt, w1, trial, rate)
        n += 1
    if n != len(GRID) * TRIALS:
        raise SystemExit(f"expected {len(GRID) * TRIALS} jobs, ran {n}")
    print(sid)


if __name__ == "__main__":
    main()
