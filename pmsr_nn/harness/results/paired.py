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


GROUPS = (("start their own tracks", lambda row: row.get("initiation") == "detections"),
          ("are handed their targets (own streams, oracle births)", lambda row: row.get("initiation") != "detections"))
"""How rows are compared: each with the best of those given the same help (a tracker that must find
its targets is compared with the best such tracker, not with a filter handed each target's stream)."""


def set_comparisons(rows: dict, per_run: dict[str, dict[str, np.ndarray]], p: float) -> list[dict]:
    """Per group of :data:`GROUPS` with at least two rows holding per-run set figures, each row
    against the group's row of lowest GOSPA: ``{"group": text, "reference": name, "runs": B,
    "beyond_se": BEYOND, "rows": {name: {"gospa_m": {"difference", "se", "verdict"}, "ospa_m":
    {...}}}}`` (differences row minus reference, m). ``rows``: name -> result row (with
    ``gospa_m`` and ``initiation``); ``per_run``: name -> ``gospa_run`` / ``ospa_run`` ``(B,)``."""
    have = [m for m in rows if m in per_run and "gospa_run" in per_run[m] and rows[m].get("gospa_m") is not None]
    out = []
    for group, member in GROUPS:
        names = [m for m in have if member(rows[m])]
        if len(names) < 2:
            continue
        ref = min(names, key=lambda m: rows[m]["gospa_m"])
        compared = {}
        for m in names:
            if m == ref:
                continue
            entry = {}
            for key, q, power in (("gospa_m", "gospa_run", p), ("ospa_m", "ospa_run", 1.0)):
                d = paired_difference(per_run[m][q], per_run[ref][q], power)
                entry[key] = {**d, "verdict": verdict(d["difference"], d["se"])}
            compared[m] = entry
        out.append({"group": group, "reference": ref, "runs": int(len(per_run[ref]["gospa_run"])),
                    "beyond_se": BEYOND, "rows": compared})
    return out


def comparison_lines(comps: list[dict] | None) -> list[str]:
    """The report's tables of :func:`set_comparisons` (empty for none)."""
    lines = []
    for comp in comps or []:
        ref = comp["reference"]
        lines += ["", f"Rows that {comp['group']}: GOSPA and OSPA minus those of {ref} (the lowest GOSPA among them), "
                      f"paired over the same {comp['runs']} runs (± s.e. of the paired difference); *behind* / *ahead* "
                      f"only beyond {comp['beyond_se']:g} s.e., else *tie*:", "",
                  "| method | GOSPA difference (m) | GOSPA | OSPA difference (m) | OSPA |", "|---|---:|---|---:|---|"]
        for m, e in comp["rows"].items():
            cells = []
            for key in ("gospa_m", "ospa_m"):
                d = e[key]
                se = "" if d["se"] is None else f" ± {d['se']:.1f}"
                cells.append(f"{d['difference']:+.1f}{se} | {d['verdict']}")
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return lines
