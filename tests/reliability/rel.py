#!/usr/bin/env python3
"""Helpers of the reliability scripts (standard library only).

    rel.py free-port
    rel.py tiny-search NAME POINTS TRIALS ENV_STEPS [mixed] > search.json
    rel.py submit URL FILE                 -> prints the search id
    rel.py wait URL ID SECONDS             -> exit 0 when completed, 1 otherwise
    rel.py healthz URL                     -> prints the HTTP status and body
    rel.py get URL PATH                    -> prints status and body
    rel.py post URL PATH JSON              -> prints status and body
    rel.py verify URL ID DB [LOG...]       -> exactly-once checks; prints figures
                                              (DB "-": through the API only)
    rel.py state URL ID [WORKER]           -> "<search status> <leases WORKER holds>"
    rel.py integrity DB                    -> prints pragma integrity_check
    rel.py metric URL NAME                 -> prints the value of a metric (0 if absent)
    rel.py accepted-ids LOG...             -> job ids with "result accepted" lines
    rel.py job-report URL ID               -> every job not done, with its attempts,
                                              leases and last error; then the most
                                              leases and attempts any job had
    rel.py grid-check URL ID BASE_SEED     -> the jobs are exactly points x trials, each
                                              (point, trial) once, with the job-seed rule's seed

Every check that fails prints "FAIL: ..." and makes `verify` exit 1.
"""

import json
import os
import re
import socket
import sqlite3
import struct
import sys
import time
import urllib.error
import urllib.request

TOKEN = os.environ.get("IRLGRID_TOKEN", "")


def call(method, url, body=None, timeout=10):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    if TOKEN:
        req.add_header("Authorization", "Bearer " + TOKEN)
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, r.read().decode(), dict(r.headers)
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode(), dict(e.headers)


def get_json(url):
    st, body, _ = call("GET", url)
    if st != 200:
        raise RuntimeError(f"GET {url}: {st} {body}")
    return json.loads(body)


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def tiny_search(name, points, trials, env_steps, mixed=False):
    """A tiny search; `mixed` runs every (point, trial) as two solver
    variants, PPO and a tiny trajectory optimizer, so that both kinds of job
    go through the same queue, leases and retries."""
    w1 = [0.5 * (k + 1) for k in range(points)]
    search = {
        "name": name,
        "reward_grid": {"w1": w1},
        "trials": trials,
        "seed": 11,
        "max_attempts": 20,
        "training": {"env_steps": env_steps, "n_envs": 16, "n_steps": 64,
                     "minibatch_size": 256, "epochs": 2},
        "sampling": {"successful_episodes": 2, "top_k": 2, "max_attempts": 48, "n_envs": 8},
    }
    if mixed:
        search["solvers"] = [
            {"name": "ppo", "kind": "ppo"},
            {"name": "optimizer", "kind": "optimizer",
             "optimizer": {"population": 32, "elites": 4, "iterations": 40, "restarts": 1}},
        ]
    return search


def log_lines(paths):
    """(message, fields) of every log line, JSON or text."""
    for p in paths:
        try:
            with open(p, errors="replace") as f:
                for line in f:
                    line = line.strip()
                    if line.startswith("{"):
                        try:
                            rec = json.loads(line)
                        except ValueError:
                            continue
                        fields = dict(rec.get("fields", {}))
                        for span in rec.get("spans", []) + [rec.get("span") or {}]:
                            for k, v in span.items():
                                fields.setdefault(k, v)
                        yield fields.get("message", ""), fields
                    else:
                        m = re.search(r"job_id=(\d+)", line)
                        yield line, ({"job_id": int(m.group(1))} if m else {})
        except FileNotFoundError:
            continue


def accepted_ids(paths):
    ids = []
    for msg, fields in log_lines(paths):
        if "result accepted" in msg and "job_id" in fields:
            ids.append(int(fields["job_id"]))
    return ids


def integrity(db):
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)
    try:
        return con.execute("pragma integrity_check").fetchone()[0]
    finally:
        con.close()


def verify(url, sid, db, logs):
    """Checks that search `sid` completed with every job done exactly once."""
    fails = []

    def check(cond, what):
        print(("PASS: " if cond else "FAIL: ") + what)
        if not cond:
            fails.append(what)

    s = get_json(f"{url}/api/v1/searches/{sid}")
    j = s["jobs"]
    check(s["status"] == "completed", f"search {sid} completed (status {s['status']})")
    check(j["done"] == j["total"] and j["total"] > 0,
          f"every job done ({j['done']}/{j['total']}, failed {j.get('failed')})")
    check(j["leased"] == 0 and j["queued"] == 0,
          f"no job left leased or queued (leased {j['leased']}, queued {j['queued']})")
    jobs = get_json(f"{url}/api/v1/searches/{sid}/jobs")
    check(len(jobs) == j["total"], f"jobs listed = total ({len(jobs)})")
    keys = [(x["point_idx"], x.get("variant", 0), x["trial"]) for x in jobs]
    check(len(set(keys)) == len(keys), "one job per (point, solver variant, trial)")
    outputs = get_json(f"{url}/api/v1/searches/{sid}/outputs")
    trials = [(w["params"]["w1"] if "w1" in w.get("params", {}) else json.dumps(w.get("params")),
               t.get("solver", {}).get("name", "ppo"), t["trial"])
              for w in outputs for t in w["trials"]]
    check(len(trials) == j["done"], f"one uploaded output per done job ({len(trials)} outputs)")
    check(len(set(trials)) == len(trials), "no (point, solver variant, trial) output twice")
    variants = sorted({k[1] for k in keys})
    print(f"  solver variants with jobs: {variants}")
    doc = get_json(f"{url}/api/v1/searches/{sid}/results")
    done_in_doc = sum(w["trials_done"] for w in doc["weights"])
    check(doc.get("partial") is False and done_in_doc == j["done"],
          f"final document: partial={doc.get('partial')}, trials_done={done_in_doc}")

    if db == "-":
        return verify_api_only(check, fails, jobs, logs)
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)
    rows = con.execute(
        "select j.id, j.status, j.lease_expires_at, j.attempts, j.lease_count,"
        " (select count(*) from job_results r where r.job_id = j.id)"
        " from jobs j where j.search_id = ?", (sid,)).fetchall()
    cached = con.execute("select final_document is not null from searches where id = ?",
                         (sid,)).fetchone()[0]
    # Jobs of other searches the same workers ran (disk_faults submits a
    # second search and cancels it; a job leased in between is done and
    # accepted). Their acceptances are not this search's.
    others = {r[0] for r in con.execute("select id from jobs where search_id != ?", (sid,))}
    con.close()
    check(all(r[5] == 1 for r in rows), "database: exactly one job_results row per job")
    check(all(r[1] == "done" and r[2] is None for r in rows),
          "database: every job done with no lease left (lease_expires_at null)")
    check(bool(cached), "database: final document cached")
    ok = integrity(db)
    check(ok == "ok", f"database: pragma integrity_check = {ok}")
    if logs:
        acc = [i for i in accepted_ids(logs) if i not in others]
        ids = {r[0] for r in rows}
        dup = sorted({i for i in acc if acc.count(i) > 1})
        check(not dup, f"worker logs: no job accepted twice ({len(acc)} acceptances logged; dup {dup})")
        check(set(acc) <= ids, "worker logs: every accepted job is a done job with its result")
    attempts = sum(r[3] for r in rows)
    leases = sum(r[4] for r in rows)
    print(f"FIGURES: jobs={len(rows)} leases={leases} re_leases={leases - len(rows)} "
          f"attempts_lost={attempts} max_leases_per_job={max(r[4] for r in rows)}")
    return 1 if fails else 0


def verify_api_only(check, fails, jobs, logs):
    """The database checks of `verify` for a database out of reach (in a
    container's volume), from the jobs listing instead."""
    check(all(j["status"] == "done" for j in jobs), "every job listed done")
    check(all(j["attempts"] == 0 for j in jobs),
          f"no attempt used ({sum(j['attempts'] for j in jobs)} used)")
    if logs:
        # The logs may hold other searches' jobs too.
        ids = {j["id"] for j in jobs}
        acc = [i for i in accepted_ids(logs) if i in ids]
        dup = sorted({i for i in acc if acc.count(i) > 1})
        check(not dup, f"worker logs: no job accepted twice ({len(acc)} acceptances logged; dup {dup})")
        # Not every acceptance need be in the logs: a task that Swarm
        # scaled down may take its log with it. That every job was done
        # exactly once is checked through the API above (one output per
        # (point, trial), every job done, no attempt used); the logs add
        # that no job was accepted twice.
        print(f"  worker logs: {len(set(acc))} of {len(ids)} jobs' acceptances found in the logs")
    leases = sum(j["lease_count"] for j in jobs)
    print(f"FIGURES: jobs={len(jobs)} leases={leases} re_leases={leases - len(jobs)} "
          f"attempts_lost={sum(j['attempts'] for j in jobs)} "
          f"workers={len({(j.get('worker') or '').rsplit('/', 1)[0] for j in jobs})}")
    return 1 if fails else 0


def job_report(url, sid):
    """Prints every job of `sid` that is not done (status, attempts, leases,
    last error), then the spread of leases and attempts over all jobs, so a
    failed soak says which job failed and why."""
    jobs = get_json(f"{url}/api/v1/searches/{sid}/jobs")
    bad = [j for j in jobs if j["status"] != "done"]
    for j in bad:
        print(f"NOT DONE: job {j['id']} point {j['point_idx']} {json.dumps(j['params'])} "
              f"trial {j['trial']}: {j['status']}, attempts {j['attempts']}, "
              f"leases {j['lease_count']}, last error: {j.get('last_error')}")
    leases = sorted(j["lease_count"] for j in jobs)
    attempts = sorted(j["attempts"] for j in jobs)
    print(f"FIGURES: jobs={len(jobs)} not_done={len(bad)} leases={sum(leases)} "
          f"max_leases_per_job={leases[-1] if leases else 0} "
          f"median_leases_per_job={leases[len(leases) // 2] if leases else 0} "
          f"max_attempts_used={attempts[-1] if attempts else 0}")
    return 1 if bad else 0


M64 = (1 << 64) - 1


def splitmix64(x):
    z = (x + 0x9E3779B97F4A7C15) & M64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M64
    return z ^ (z >> 31)


def fnv1a64(s):
    h = 0xCBF29CE484222325
    for b in s.encode():
        h = ((h ^ b) * 0x100000001B3) & M64
    return h


def job_seed(base, params, trial):
    """shared::api::job_seed, independently."""
    h = splitmix64(base & M64)
    for name in sorted(params):
        v = float(params[name])
        v = 0.0 if v == 0 else v
        bits = struct.unpack("<Q", struct.pack("<d", v))[0]
        h = splitmix64(h ^ fnv1a64(name))
        h = splitmix64(h ^ bits)
    return splitmix64(h ^ trial)


def grid_check(url, sid, base):
    """The search's jobs are exactly its points x trials 0..trials-1, one
    job each, with the seed of the job-seed rule (a search without
    replacements)."""
    s = get_json(f"{url}/api/v1/searches/{sid}")
    jobs = get_json(f"{url}/api/v1/searches/{sid}/jobs")
    fails = []
    keys = [(json.dumps(j["params"], sort_keys=True), j["trial"]) for j in jobs]
    points = sorted({k[0] for k in keys})
    if len(set(keys)) != len(keys):
        fails.append(f"a (point, trial) appears twice among {len(keys)} jobs")
    if len(points) != s["points"]:
        fails.append(f"{len(points)} points have jobs, the search has {s['points']}")
    want = {(p, t) for p in points for t in range(s["trials"])}
    if set(keys) != want:
        fails.append(f"jobs are not points x trials: missing {sorted(want - set(keys))[:5]}, "
                     f"extra {sorted(set(keys) - want)[:5]}")
    bad = [(j["params"], j["trial"]) for j in jobs
           if j["seed"] != job_seed(base, j["params"], j["trial"])]
    if bad:
        fails.append(f"seeds off the rule: {bad[:5]}")
    for f in fails:
        print("FAIL: " + f)
    print(f"grid {s['points']} points x {s['trials']} trials, {len(jobs)} jobs"
          + ("" if fails else ": exact"))
    return 1 if fails else 0


def metric(url, name):
    st, body, _ = call("GET", f"{url}/metrics")
    total = 0.0
    for line in body.splitlines():
        if line.startswith(name + " ") or line.startswith(name + "{"):
            total += float(line.rsplit(" ", 1)[1])
    return total


def main(argv):
    cmd = argv[1]
    if cmd == "free-port":
        print(free_port())
    elif cmd == "tiny-search":
        mixed = len(argv) > 6 and argv[6] == "mixed"
        print(json.dumps(tiny_search(argv[2], int(argv[3]), int(argv[4]), int(argv[5]), mixed)))
    elif cmd == "submit":
        with open(argv[3]) as f:
            body = json.load(f)
        st, text, _ = call("POST", f"{argv[2]}/api/v1/searches", body)
        if st != 201:
            print(f"submit failed: {st} {text}", file=sys.stderr)
            return 1
        print(json.loads(text)["id"])
    elif cmd == "wait":
        url, sid, limit = argv[2], argv[3], float(argv[4])
        t0 = time.time()
        while time.time() - t0 < limit:
            try:
                s = get_json(f"{url}/api/v1/searches/{sid}")
                if s["status"] != "running":
                    return 0 if s["status"] == "completed" else 1
            except (OSError, RuntimeError, ValueError):
                pass
            time.sleep(0.5)
        return 1
    elif cmd == "healthz":
        try:
            st, body, _ = call("GET", f"{argv[2]}/healthz", timeout=15)
        except OSError as e:
            st, body = 0, str(e)
        print(st, body)
    elif cmd == "get":
        st, body, _ = call("GET", argv[2] + argv[3])
        print(st, body)
    elif cmd == "post":
        st, body, headers = call("POST", argv[2] + argv[3], json.loads(argv[4]), timeout=30)
        retry = {k.lower(): v for k, v in headers.items()}.get("retry-after")
        print(st, body, "retry-after=" + str(retry))
    elif cmd == "verify":
        return verify(argv[2], argv[3], argv[4], argv[5:])
    elif cmd == "state":
        # state URL ID [WORKER]: "<search status> <leases WORKER holds>"
        try:
            st = get_json(f"{argv[2]}/api/v1/searches/{argv[3]}")["status"]
            held = 0
            if len(argv) > 4:
                jobs = get_json(f"{argv[2]}/api/v1/searches/{argv[3]}/jobs")
                held = sum(1 for j in jobs if j["status"] == "leased"
                           and (j.get("worker") or "").startswith(argv[4] + "/"))
            print(st, held)
        except (OSError, RuntimeError, ValueError):
            print("unknown 0")
    elif cmd == "integrity":
        print(integrity(argv[2]))
    elif cmd == "metric":
        v = metric(argv[2], argv[3])
        print(int(v) if v == int(v) else v)
    elif cmd == "job-report":
        return job_report(argv[2], argv[3])
    elif cmd == "grid-check":
        return grid_check(argv[2], argv[3], int(argv[4]))
    elif cmd == "accepted-ids":
        print(" ".join(map(str, accepted_ids(argv[2:]))))
    else:
        print(__doc__, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
