#!/usr/bin/env python3
"""The worker token can do a worker's work and nothing else.

    worker_token_check.py URL WORKER_TOKEN SEARCH_ID

Run against a coordinator whose workers hold only the worker token, after
the search SEARCH_ID has completed. Checks, with the worker token:
  * POST /api/v1/leases answers 200 or 204 (it may lease; a job it gets is
    released at once, with the same token);
  * POST /api/v1/searches (submit) answers 403;
  * GET /api/v1/searches/SEARCH_ID and .../results (read) answer 403;
and that the coordinator counted heartbeats and accepted uploads
(irlgrid_heartbeats_total, irlgrid_uploads_accepted_total > 0), which only
the workers, holding the worker token, sent. Prints one PASS line per check;
exit 1 and a FAIL line on the first that does not hold.

Used by tests/compose/smoke.sh, .ci/steps/swarm.sh and .ci/steps/slurm.sh.
"""

import json
import sys
import urllib.error
import urllib.request


def call(url, token, method, path, body=None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url + path, data=data, method=method)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    if token:
        req.add_header("Authorization", "Bearer " + token)
    try:
        with urllib.request.urlopen(req, timeout=40) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


def metric(url, name):
    _, text = call(url, None, "GET", "/metrics")
    total = 0.0
    for line in text.splitlines():
        if line.startswith(name + " ") or line.startswith(name + "{"):
            total += float(line.rsplit(" ", 1)[1])
    return total


def main(argv):
    if len(argv) != 4:
        print(__doc__, file=sys.stderr)
        return 2
    url, token, sid = argv[1].rstrip("/"), argv[2], argv[3]

    def expect(what, got, want):
        if got[0] not in want:
            print(f"FAIL: worker token: {what} answered {got[0]} {got[1][:200]}, want {' or '.join(map(str, want))}")
            sys.exit(1)
        print(f"PASS: worker token: {what} -> {got[0]}")

    lease = call(url, token, "POST", "/api/v1/leases", {"worker": "token-check", "wait_secs": 0})
    expect("lease", lease, (200, 204))
    if lease[0] == 200:
        job = json.loads(lease[1])
        released = call(url, token, "POST", f"/api/v1/jobs/{job['job_id']}/release",
                        {"lease_token": job["lease_token"]})
        expect("release", released, (200,))
    submit = {"reward_grid": {"w1": [1.0]}, "trials": 1}
    expect("submit a search", call(url, token, "POST", "/api/v1/searches", submit), (403,))
    expect("read a search", call(url, token, "GET", f"/api/v1/searches/{sid}"), (403,))
    expect("read results", call(url, token, "GET", f"/api/v1/searches/{sid}/results"), (403,))
    for name in ("irlgrid_heartbeats_total", "irlgrid_uploads_accepted_total"):
        n = metric(url, name)
        if n <= 0:
            print(f"FAIL: {name} is {n}: the workers (worker token only) sent none")
            return 1
        print(f"PASS: {name} = {n:g}, sent by workers holding only the worker token")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
