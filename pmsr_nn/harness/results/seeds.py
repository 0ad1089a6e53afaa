"""Learned trackers over training seeds, and paired margins against the classical methods.

A learned result from one training seed is an anecdote: identically configured networks land far
apart from one seed to the next. A scenario lists each seed as its own method named
``BASE [seed k]``; these helpers group such rows and summarise them (mean, spread), and measure
how far a learned tracker is ahead of (or behind) a classical one *on the same Monte Carlo runs*:
the per-run difference of position RMSE, with its standard error over runs.
"""

from __future__ import annotations

import re

import numpy as np

SEED_NAME = re.compile(r"^(?P<base>.+?) \[seed (?P<seed>\d+)\]$")


def seed_groups(names) -> dict[str, list[str]]:
    """``BASE -> [method names]`` for the names of the form ``BASE [seed k]``, in order of first
    appearance; other names are left out."""
    groups: dict[str, list[str]] = {}
    for name in names:
        m = SEED_NAME.match(name)
        if m:
            groups.setdefault(m["base"], []).append(name)
    return groups


def learned_units(methods: dict) -> dict[str, list[str]]:
    """Each learned tracker of a case's ``methods`` (name -> row with ``kind``) as one unit: a
    seed group, or a single learned method under its own name."""
    learned = [n for n, r in methods.items() if r["kind"] == "learned"]
    groups = seed_groups(learned)
    grouped = {n for g in groups.values() for n in g}
    units = {n: [n] for n in learned if n not in grouped}
    return {**groups, **units}


def _stats(values) -> dict:
    v = np.asarray(values, dtype=float)
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
            "min": float(v.min()), "max": float(v.max())}


def summarise_seeds(methods: dict) -> dict:
    """Per seed group of ``methods`` (name -> result row): its members and the mean, standard
    deviation (over seeds), min and max of position RMSE and of its ratios to the bounds."""
    out = {}
    for base, names in seed_groups(methods).items():
        rows = [methods[n] for n in names]
        entry = {"methods": names, "seeds": len(names), "rmse_pos_m": _stats([r["rmse_pos_m"] for r in rows]),
                 "over_bound": _stats([r["over_bound"] for r in rows])}
        if all("over_memory_bound" in r for r in rows):
            entry["over_memory_bound"] = _stats([r["over_memory_bound"] for r in rows])
        out[base] = entry
    return out


def paired_margin(learned_run_rmse: list[np.ndarray], classical_run_rmse: np.ndarray) -> dict:
    """How far a learned tracker (per-run RMSE ``(B,)`` of each seed) is below a classical one
    (``(B,)``) on the same runs: mean over runs of ``classical - mean over seeds of learned``
    (positive: the learned tracker is better) and its standard error over runs."""
    d = np.asarray(classical_run_rmse, float) - np.mean(np.stack(learned_run_rmse), 0)
    se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("inf")
    return {"margin_m": float(d.mean()), "se_m": se, "runs": int(len(d))}


def comparisons(methods: dict, run_rmse: dict[str, np.ndarray]) -> list[dict]:
    """Every learned unit (:func:`learned_units`) against the case's best classical method (lowest
    ``rmse_pos_m`` among the non-learned estimators), paired over the runs (:func:`paired_margin`)."""
    classical = {n: r for n, r in methods.items() if r["kind"] not in ("learned", "pcrb")}  # a bound estimates nothing
    if not classical:
        return []
    best = min(classical, key=lambda n: classical[n]["rmse_pos_m"])
    out = []
    for unit, names in learned_units(methods).items():
        out.append({"learned": unit, "seeds": len(names), "classical": best,
                    **paired_margin([run_rmse[n] for n in names], run_rmse[best])})
    return out
