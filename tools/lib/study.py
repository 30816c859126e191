"""Readers of one reward study directory (tools/reward_study.sh), shared by
tools/reward_table.py and tools/shape_price.py."""
import json
import pathlib


def optima(out: pathlib.Path) -> dict:
    """The optimizer's answers (optimum.json: one object or a list) by w1;
    empty when the study skipped the optimizer."""
    f = out / "optimum.json"
    if not f.exists():
        return {}
    opt = json.loads(f.read_text())
    if isinstance(opt, dict):
        opt = [opt]
    return {o["env"]["reward"]["w1"]: o for o in opt}


def used_trial_areas(weight: dict) -> list:
    """(seed, path area) of every trial of one `irlgrid analyze` weight entry
    that went into its weight mean: the trials behind `area_mean`."""
    return [(t["seed"], t["area"]) for t in weight["trials"]
            if t.get("used") and t.get("area") is not None]
