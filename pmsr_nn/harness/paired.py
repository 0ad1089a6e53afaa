"""Rows of one case against each other on the same Monte Carlo runs: paired differences of
GOSPA and OSPA, with their standard errors.

Every row of a case reads the same truth and the same detections in every run, so the run-to-run
variation of the scene (a crossing that happens to be hard in run 7) is shared by the rows and
cancels in their per-run difference: the difference of two rows is known much more precisely
than the two cells' own errors suggest. A row is called ahead of or behind another only where the
difference exceeds :data:`BEYOND` standard errors; otherwise the two tie.

GOSPA is reported as ``f(A) = A ** (1/p)``, ``A`` the mean over runs and scans of GOSPA^p; with
``a_i`` each run's mean over the scans (``A = mean a_i``), the difference ``f(A) - f(B)`` has by
the delta method the standard error of the mean of ``f'(A) a_i - f'(B) b_i``. OSPA is reported as
the plain mean of the per-run means (``p = 1``).
"""

from __future__ import annotations

import numpy as np

BEYOND = 2.0
"""Standard errors a paired difference must exceed to call one row ahead of another (with 50 runs,
about the two-sided 95 % Student-t point)."""


def paired_difference(a: np.ndarray, b: np.ndarray, p: float = 1.0) -> dict:
    """``f(mean a) - f(mean b)`` with ``f(x) = x ** (1/p)`` for per-run values ``a, b (B,)`` of the
    same runs, and its standard error (None with fewer than two runs or a zero mean)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ma, mb = float(a.mean()), float(b.mean())
    diff = ma ** (1.0 / p) - mb ** (1.0 / p)
    if len(a) < 2 or ma <= 0 or mb <= 0:
        return {"difference": diff, "se": None}
    slope = lambda m: m ** (1.0 / p - 1.0) / p  # f'(m)
    d = slope(ma) * a - slope(mb) * b
    return {"difference": diff, "se": float(d.std(ddof=1) / np.sqrt(len(d)))}


def verdict(difference: float, se: float | None) -> str:
    """``"ahead"`` (lower), ``"behind"`` or ``"tie"`` for a difference of a row minus another."""
    if se is None or not abs(difference) > BEYOND * se:
        return "tie"
    return "ahead" if difference < 0 else "behind"


def set_comparisons(rows: dict, per_run: dict[str, dict[str, np.ndarray]], p: float) -> dict | None:
    """Each row with per-run set figures against the row of lowest GOSPA: ``{"reference": name,
    "runs": B, "beyond_se": BEYOND, "rows": {name: {"gospa_m": {"difference", "se", "verdict"},
    "ospa_m": {...}}}}`` (differences row minus reference, m); None with fewer than two such rows.
    ``rows``: name -> result row (with ``gospa_m``); ``per_run``: name -> ``gospa_run`` / ``ospa_run``."""
    have = [m for m in rows if m in per_run and "gospa_run" in per_run[m] and rows[m].get("gospa_m") is not None]
    if len(have) < 2:
        return None
    ref = min(have, key=lambda m: rows[m]["gospa_m"])
    out = {}
    for m in have:
        if m == ref:
            continue
        entry = {}
        for key, q, power in (("gospa_m", "gospa_run", p), ("ospa_m", "ospa_run", 1.0)):
            d = paired_difference(per_run[m][q], per_run[ref][q], power)
            entry[key] = {**d, "verdict": verdict(d["difference"], d["se"])}
        out[m] = entry
    return {"reference": ref, "runs": int(len(per_run[ref]["gospa_run"])), "beyond_se": BEYOND, "rows": out}


def comparison_lines(comp: dict | None) -> list[str]:
    """The report's table of :func:`set_comparisons` (empty for None)."""
    if not comp:
        return []
    ref = comp["reference"]
    lines = ["", f"GOSPA and OSPA of each row minus those of {ref} (the lowest GOSPA), paired over the same "
                 f"{comp['runs']} runs (± s.e. of the paired difference); *behind* / *ahead* only beyond "
                 f"{comp['beyond_se']:g} s.e., else *tie*:", "",
             "| method | GOSPA difference (m) | GOSPA | OSPA difference (m) | OSPA |", "|---|---:|---|---:|---|"]
    for m, e in comp["rows"].items():
        cells = []
        for key in ("gospa_m", "ospa_m"):
            d = e[key]
            se = "" if d["se"] is None else f" ± {d['se']:.1f}"
            cells.append(f"{d['difference']:+.1f}{se} | {d['verdict']}")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return lines
