"""Writes a finished search's aggregation input, as the coordinator's
`GET /api/v1/searches/{id}/outputs` serves it, from its SQLite database:
for `irlgrid holdout --outputs FILE` and `irlgrid analyze --outputs FILE`
on a search whose coordinator is no longer running.

    python3 tools/lib/search_outputs.py DB [SEARCH_ID] > outputs.json

SEARCH_ID defaults to the database's only (or latest) search."""
import json
import sqlite3
import sys

db = sys.argv[1]
con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
sid = sys.argv[2] if len(sys.argv) > 2 else con.execute(
    "select id from searches order by seq desc limit 1").fetchone()[0]
config = json.loads(con.execute("select config from searches where id = ?", (sid,)).fetchone()[0])
solvers = [{"name": s["name"], "kind": s["kind"]} for s in config.get("solvers", [])] or \
    [{"name": "ppo", "kind": "ppo"}]
points = {idx: json.loads(p) for idx, p in
          con.execute("select idx, params from points where search_id = ?", (sid,))}
weights = {idx: {"params": p, "trials": []} for idx, p in points.items()}
rows = con.execute(
    "select j.point_idx, j.variant, j.trial, j.seed, r.converged, r.output"
    " from jobs j join job_results r on r.job_id = j.id where j.search_id = ?"
    " order by j.point_idx, j.variant, j.trial", (sid,))
for idx, variant, trial, seed, converged, output in rows:
    o = json.loads(output)
    weights[idx]["trials"].append({
        "trial": trial, "seed": seed & 0xFFFFFFFFFFFFFFFF,
        "final_success_rate": o["final_success_rate"], "converged": bool(converged),
        "episodes": o["episodes"], "successes_found": o["successes_found"],
        "successes_wanted": o["successes_wanted"], "solver": solvers[variant]})


def key(w):
    return sorted(w["params"].items())


json.dump(sorted(weights.values(), key=key), sys.stdout)
