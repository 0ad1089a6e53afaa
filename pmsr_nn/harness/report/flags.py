"""Honesty flags: rows below their bound, the q = 0 floor or their finite-memory bound beyond the
Monte Carlo error, diverged runs, and runs in which a row reported no track at all. The report's
paragraphs (:func:`flag_paragraphs`) and the console's lines (:func:`warning_lines`) say the same flags.

A row is below a bound when the runner's rule holds (``below`` in its results: the one-sided
97.5 % Student-t bound of the mean over runs of the run's mean squared position error over the
bound's mean square is under 1); each flag states that ratio, its standard error and how many
standard errors it lies under 1. Results written before the standard error was kept flag as
recorded and say that the error is unknown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ..results.result_rows import MethodRow
from ..results.typed import Results
from .report_cells import fmt, fmt_se, span

AGAINST = {"bound": "bound^2", "floor": "floor^2", "memory": "bound^2"}


@dataclass(frozen=True)
class Below:
    """``method`` on ``case`` under a bound (``bound``: its filtering or smoothing PCRB; ``floor``:
    that bound with q = 0; ``memory``: its finite-memory bound): the mean MSE ratio and its
    standard error over runs (None where the results do not hold it)."""

    case: str
    method: str
    row: MethodRow
    against: Literal["bound", "floor", "memory"]
    ratio: float | None
    se: float | None

    @property
    def has_error(self) -> bool:
        return self.ratio is not None and self.se is not None and math.isfinite(self.se) and self.se > 0

    def interval(self, sign: str = "+-", digits: int = 3) -> str:
        """``MSE / bound^2 0.805 +- 0.007``: the mean ratio and its standard error (empty without one)."""
        if not self.has_error:
            return ""
        return f"MSE / {AGAINST[self.against]} {self.ratio:.{digits}f} {sign} {self.se:.{digits}f}"

    def distance(self) -> str:
        """``29.5 s.e. below 1``: how far the ratio lies under 1 in standard errors."""
        return f"{(1 - self.ratio) / self.se:.1f} s.e. below 1" if self.has_error else ""

    def metres(self) -> str:
        """``RMSE 10.90 m against the bound 12.34 m`` (empty where the row lacks either)."""
        r = self.row
        bound = {"bound": r.bound and r.bound.pos_m, "floor": r.bound and r.bound.q0_pos_m,
                 "memory": r.memory and r.memory.pos_m}[self.against]
        if r.rmse_pos_m is None or bound is None:
            return ""
        name = {"bound": "the bound", "floor": "the floor", "memory": "the finite-memory bound"}[self.against]
        return f"RMSE {fmt_se(r.rmse_pos_m, r.rmse_pos_se_m)} m against {name} {fmt(bound)} m"

    def entry(self) -> str:
        """The flag in a report's list: ``EKF on c (MSE / bound^2 0.805 +- 0.007), 29.5 s.e. below 1:
        RMSE 10.90 m against the bound 12.34 m``."""
        text, metres = f"{self.method} on {self.case}", self.metres()
        if self.has_error:
            return f"{text} ({self.interval()}), {self.distance()}" + (f": {metres}" if metres else "")
        return text + (f" ({metres})" if metres else "")


def below(results: Results, against: Literal["bound", "floor", "memory"]) -> list[Below]:
    """Every row under ``against`` as its results say (the floor: among the rows under their bound)."""
    out = []
    for c, m, r in results.rows():
        if against == "memory":
            if r.memory is not None and r.memory.below:
                out.append(Below(c, m, r, against, r.memory.mse_ratio, r.memory.mse_ratio_se))
        elif r.bound is not None and r.bound.below and (against == "bound" or r.bound.below_q0):
            b = r.bound
            ratio, se = (b.mse_ratio, b.mse_ratio_se) if against == "bound" else (b.q0_mse_ratio, b.q0_mse_ratio_se)
            out.append(Below(c, m, r, against, ratio, se))
    return out


def diverged(results: Results) -> list[tuple[str, str, MethodRow]]:
    """``(case, method, row)`` of every row with diverged runs."""
    return [(c, m, r) for c, m, r in results.rows() if r.diverged_runs]


def trackless(results: Results) -> list[tuple[str, str, MethodRow]]:
    """``(case, method, row)`` of every row that reported no track at all in some run (results
    written before the count was kept flag nothing)."""
    return [(c, m, r) for c, m, r in results.rows() if r.tracks is not None and r.tracks.runs_without_tracks]


def _trackless_entry(case: str, method: str, r: MethodRow) -> str:
    return f"{method} reported no track in {r.tracks.runs_without_tracks} of {r.runs} runs on {case}"


TRACKLESS_HINT = "its existence update or reporting threshold may be wrong"
"""What a row that reports no track in a whole run most often has wrong (said with its flag)."""


def _floor_sentence(floor: list[Below]) -> str:
    """What the report says of the rows below the q = 0 floor (ending the bound's paragraph)."""
    if not floor:
        return "no method is below it beyond its Monte Carlo error."
    known = [f for f in floor if f.has_error]
    unknown = [f for f in floor if not f.has_error]
    text = []
    if known:
        text.append("**" + "; ".join(f.entry() for f in known) + " is below even that floor, beyond its Monte Carlo "
                    "error: a bug or a mismatch to investigate.**")
    if unknown:
        text.append("**" + "; ".join(f.entry() for f in unknown) + " is below even that floor as recorded (no Monte "
                    "Carlo error recorded): rerun to investigate.**")
    return " ".join(text)


def flag_paragraphs(res: Results | dict) -> list[str]:
    """The report's paragraphs on the rows below their bound (and the floor), on diverged runs and
    on rows that reported no track in some run."""
    results = Results.of(res)
    lines = []
    flagged = below(results, "bound")
    if flagged:
        known = [f for f in flagged if f.has_error]
        unknown = [f for f in flagged if not f.has_error]
        anees = [f.row.anees for f in flagged if f.row.anees is not None]
        head = []
        if known:
            head.append("**Below the bound (bold; beyond the Monte Carlo error: the one-sided 97.5 % Student-t bound "
                        "of the per-run mean squared error over the bound's mean square is under 1):** "
                        + "; ".join(f.entry() for f in known) + ".")
        if unknown:
            head.append(("**Below the bound (bold) as these results recorded it, without its Monte Carlo error** "
                         "(written before the standard error was kept; rerun to tell it from chance): ")
                        + "; ".join(f.entry() for f in unknown) + ".")
        floor_text = _floor_sentence(below(results, "floor"))
        lines += [" ".join(head) + " "
                  "The per-trajectory PCRB assumes, like the filters, the process noise q of the motion model; "
                  "the designed trajectories have no such process noise, so a filter's error on them "
                  "lacks the part the bound reserves for it"
                  + (f" (the flagged methods' ANEES of {span(anees)} says the same: their errors are "
                     "smaller than their own covariances)" if anees else "") +
                  ". The floor for these flights is the bound with q = 0 (last row); " + floor_text, ""]
    runs = diverged(results)
    if runs:
        lines += ["**Diverged runs** (position RMSE after the warm-up above "
                  f"{results.settings.divergence_m:g} m or not finite; kept in every average, see the median per run in "
                  "results.json): " + ", ".join(f"{m} {r.diverged_runs}/{r.runs} on {c}" for c, m, r in runs) + ".", ""]
    silent = trackless(results)
    if silent:
        lines += ["**No track reported:** " + "; ".join(_trackless_entry(*t) for t in silent) + f": {TRACKLESS_HINT} "
                  "(a tracker whose tracks' existence never reaches its reporting threshold reports nothing, and "
                  "GOSPA then counts every target missed).", ""]
    return lines


def warning_lines(res: Results | dict, prefix: str = "warning   ") -> list[str]:
    """One console line per flag of the report: rows below their bound, the floor or their
    finite-memory bound, rows with diverged runs and rows with runs of no track (empty when the
    report flags nothing)."""
    results = Results.of(res)
    lines = []
    for against, what in (("bound", "below its {which} bound"), ("floor", "below even the q = 0 floor"),
                          ("memory", "below its finite-memory bound")):
        for f in below(results, against):
            which = f.row.bound.which if f.row.bound else ""
            said = what.format(which=which)
            if f.has_error:
                lines.append(f"{prefix}{f.method} on {f.case} {said}: {f.interval('±', 2)}, {f.distance()}")
            else:
                lines.append(f"{prefix}{f.method} on {f.case} {said} as recorded (no Monte Carlo error in the results)")
    for c, m, r in diverged(results):
        lines.append(f"{prefix}{m} on {c}: {r.diverged_runs} of {r.runs} runs diverged (position RMSE above "
                     f"{results.settings.divergence_m:g} m or not finite; kept in the averages)")
    for c, m, r in trackless(results):
        lines.append(f"{prefix}{_trackless_entry(c, m, r)}: {TRACKLESS_HINT}")
    return lines
