"""How the report writes a number, a number with its Monte Carlo error, a row's marks, and which
switches a case's tables show."""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..results.result_rows import MethodRow


def fmt(v, digits: int = 2) -> str:
    """``v`` with ``digits`` decimals; ``-`` for None, ``nan`` / ``inf`` as they are."""
    if v is None:
        return "-"
    if isinstance(v, float) and not np.isfinite(v):
        return str(v)
    return f"{v:.{digits}f}"


def fmt_se(v, se, digits: int = 2, sign: str = "±") -> str:
    """``v`` and, where the results hold one, its standard error over runs (``v ± se``)."""
    cell = fmt(v, digits)
    if v is None or se is None or not np.isfinite(se):
        return cell
    return f"{cell} {sign} {se:.{digits}f}"


def span(values) -> str:
    """``lo-hi`` of ``values`` with two decimals (one number where they agree)."""
    lo, hi = min(values), max(values)
    return f"{lo:.2f}" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}-{hi:.2f}"


def general(v) -> str:
    """A grid value as short as it goes (``%g``), or its text."""
    return f"{v:g}" if isinstance(v, (int, float)) else str(v)


def space_mark(row: MethodRow | None) -> str:
    """`` [pair 0: range, range-rate]`` for a row scored in a measurement space, so that its
    figures are never read as Cartesian ones; empty otherwise."""
    return f" [{row.space.key}: range, range-rate]" if row is not None and row.space else ""


def starts(row: MethodRow) -> str:
    """How a row's tracks start, where it is not its own initiator: said in every row it applies to."""
    return {"oracle": " (oracle births)", "association known": " (association known)"}.get(row.initiation, "")


def start_label(row: MethodRow, reads: str | None) -> str:
    """A row's ``initiation`` as a table cell: ``own`` for a row with its own initiator, with what
    it starts tracks from where the table has no column for it (``reads``: detections, or
    range-Doppler maps), so that a map row never reads as starting from detections."""
    if row.initiation == "detections":
        return "own" + (f", from {reads}" if reads else "")
    return row.initiation or "-"


SWEEP_LABELS = {"pd": "detection probability Pd", "clutter_per_scan": "clutter points per sensor per scan",
                "spacing_m": "spacing of the formation (m)"}
"""Axis and column labels of a multi-target study's swept quantity."""


def switch_column(rows: dict[str, MethodRow]) -> tuple[str, Callable]:
    """The switches a case's tables show: CLEAR MOT identity switches where its rows hold them,
    else (results recorded before them) label switches; the column's header and each row's value
    from its set figures (None for a row without them)."""
    if any(r.sets is not None and r.sets.id_switches_per_run is not None for r in rows.values()):
        return "ID switches / run (CLEAR MOT)", lambda s: s and s.id_switches_per_run
    return "label switches / run", lambda s: s and s.label_switches_per_run
