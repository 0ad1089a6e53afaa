"""Per-run set figures of banked blocks, checked against the scans the case scores (its set scans).

Each block keeps, per case and method, its per-scan sums of GOSPA^p's parts and of OSPA ``(K,)``
and each run's mean of them over the set scans (``gospa_run``, ``ospa_run``; what the Monte
Carlo errors, the run quantiles and the paired comparisons read). Before issue 55 a scenario with
an ``rd_maps:`` section averaged the per-run figures over every scan, so blocks made then do not
agree with today's set scans. The per-scan sums are the same under either rule, so a block of one
run carries everything needed: its per-run figures are its per-scan sums averaged over today's set
scans. :func:`rescore_runs` checks every block and re-derives those of one run; a block of several
runs that disagrees cannot be re-derived (its per-scan sums add its runs) and is refused.

The check: the sum over a block's runs of ``gospa_run`` equals the mean over the set scans of the
block's per-scan sums (the two sums commute), to float64 rounding.
"""

from __future__ import annotations

import numpy as np

from ...errors import ConfigError
from .block_sums import BlockSums

AGREE_RTOL = 1e-9
"""Relative tolerance of the check: float64 sums of at most ~1e5 terms (runs x scans) in another
order differ by at most ~1e5 x 1.1e-16 = 1e-11 of their value; a block scored over other scans
differs by the share of GOSPA^p in the scans it added or left out (0.1-0.8 on one_sky)."""

_GOSPA_PARTS = ("gospa_loc", "gospa_missed", "gospa_false")


def _agree(derived: float, kept: float) -> bool:
    return abs(derived - kept) <= AGREE_RTOL * max(abs(derived), abs(kept), 1e-300)


def _per_scan(qs: dict, i: int) -> dict[str, np.ndarray]:
    """Block ``i``'s per-scan sums ``(K,)`` that the per-run figures average."""
    return {"gospa_run": sum(qs[q][i] for q in _GOSPA_PARTS), "ospa_run": qs["ospa"][i]}


def rescore_runs(parts: list[BlockSums], set_scans: dict[str, np.ndarray], runs_of_block) -> list[int]:
    """Check every block of ``parts`` (stacked, as read from shards) against ``set_scans`` (case
    name -> ``(K,)`` bool); a block of one run that disagrees has its ``gospa_run`` and ``ospa_run``
    re-derived in place from its per-scan sums. ``runs_of_block(b)``: the number of runs of block
    ``b``. Returns the blocks re-derived; raises :class:`ConfigError` for a block of several runs
    that disagrees, or one that also keeps a trajectory GOSPA (``tgospa_run``, not per scan)."""
    redone = set()
    for part in parts:
        starts = np.concatenate([[0], np.cumsum([runs_of_block(b) for b in part.blocks])])
        for case, per in part.sums.items():
            k = np.asarray(set_scans[case], dtype=bool)
            if not k.any():
                continue
            for method, qs in per.items():
                if "gospa_run" not in qs or "ospa" not in qs:
                    continue
                for i, b in enumerate(part.blocks):
                    runs = slice(starts[i], starts[i + 1])
                    scans = _per_scan(qs, i)
                    if all(_agree(float(v[k].mean()), float(qs[q][runs].sum())) for q, v in scans.items()):
                        continue
                    if starts[i + 1] - starts[i] != 1 or "tgospa_run" in qs:
                        raise ConfigError(
                            f"block {b} ({case}, {method}) was scored over other scans than the case's set scans "
                            f"(scans {int(np.argmax(k))}..{len(k) - 1}) and holds {starts[i + 1] - starts[i]} runs"
                            + (" and a trajectory GOSPA" if "tgospa_run" in qs else "")
                            + ": its per-run figures cannot be re-derived; run that block again")
                    for q, v in scans.items():
                        qs[q] = qs[q].copy()
                        qs[q][runs] = v[k].mean()
                    redone.add(b)
    return sorted(redone)
