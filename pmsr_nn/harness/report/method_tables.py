"""Tables of every scenario: position RMSE of every method in every case (the paper's beside),
run time per method, and the grid searches of tuned options."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..results.typed import Results
from ..scenario.references import paper_value
from .report_cells import fmt, fmt_se, general, space_mark


def summary_table(res: Results | dict, ref: dict | None, ref_label: str, single_case: bool) -> list[str]:
    """Methods x cases, ours (± its standard error over runs where the results hold it) beside the
    paper's (the layout of the MDFNN paper's Table 6); bold: below its bound beyond the Monte Carlo
    error. Designed cases add the PCRB rows."""
    results = Results.of(res)
    cases = results.cases
    names = list(cases)
    head = "| method | " + " | ".join(f"{c} ours | {c} {ref_label}" if ref else f"{c}" for c in names) + " |"
    lines = [head, "|---|" + "---:|" * (len(names) * (2 if ref else 1))]
    methods = list(dict.fromkeys(m for _, m, _ in results.rows()))  # a case may run some only
    for m in methods:
        cells = []
        for c in names:
            r = cases[c].methods.get(m)
            if r is None:  # not run in this case
                cells += ["-"] + (["-"] if ref else [])
                continue
            v = fmt_se(r.rmse_pos_m, r.rmse_pos_se_m)
            cells.append(f"**{v}**" if r.below_bound else v)
            if ref:
                cells.append(fmt(paper_value(ref, c, m, single_case)))
        first = next(case.methods[m] for case in cases.values() if m in case.methods)
        lines.append(f"| {m}{space_mark(first)} | " + " | ".join(cells) + " |")
    if not results.designed:
        return lines
    for key, label in (("pos_m", "PCRB (filtering, per trajectory)"), ("q0_pos_m", "PCRB with q = 0 (floor)")):
        cells = [cell for c in names for cell in [fmt(getattr(cases[c].pcrb, key))] + (["-"] if ref else [])]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def timing_table(res: Results | dict, ref_timing: dict | None, ref_label: str) -> list[str]:
    """Milliseconds per run of every method (median over cases), the paper's beside."""
    results = Results.of(res)
    cases = list(results.cases.values())
    methods = list(dict.fromkeys(m for _, m, _ in results.rows()))  # a case may run some methods only
    mc = results.mc_runs
    lines = [f"| method | ms per run (median over cases) | ms for {mc} runs of one case | {ref_label}: ms |",
             "|---|---:|---:|---:|"]
    for m in methods:
        ran = [c.methods[m].seconds_per_run for c in cases if m in c.methods]
        if ran[0] is None:  # a bound's row: nothing was run
            continue
        s = float(np.median(ran))
        ref = ref_timing.get(m) if ref_timing else None
        ref = ref if isinstance(ref, (int, float)) else None  # a study's per-case times go in its own table
        lines.append(f"| {m} | {1e3 * s:.2f} | {1e3 * s * mc:.0f} | {fmt(ref, 1)} |")
    lines += ["", f"Wall-clock of whole calls on blocks of {results.settings.block_runs} runs x {cases[0].steps} scans "
              "(all runs of a block at once, all targets), divided by the runs; learned trackers include windowing and "
              "splicing."]
    if ref_timing and ref_timing.get("_note"):
        lines.append(f"{ref_label.capitalize()}: {ref_timing['_note']}.")
    return lines


def tuning_tables(res: Results | dict) -> list[str]:
    """One table per method with tuned options: every grid point's position RMSE on the tuning
    tracks, the chosen point in bold (empty when no option was tuned)."""
    results = Results.of(res)
    tuned = {m: s.tuning for m, s in results.settings.methods.items() if s.tuning is not None}
    if not tuned:
        return []
    first = next(iter(tuned.values()))
    lines = ["## Tuned options", "",
             f"Options marked `tuned` were chosen by a grid search on {first.tracks} tracks of {first.steps} steps "
             f"drawn from the training recipe `{Path(first.recipe).name}` (seed {first.seed}, apart from the "
             "evaluation's draws), measured with this scenario's noise: the point with the lowest position RMSE after "
             f"the warm-up ({first.warmup_steps} steps, Eq. 31) is used (bold).", ""]
    for name, t in tuned.items():
        keys = t.options
        chosen = ", ".join(f"{k} = {general(t.chosen[k])}" for k in keys)
        lines += [f"**{name}**: {chosen} (RMSE {fmt(t.rmse_pos_m)} m on the tuning tracks; {len(t.points)} points, "
                  f"{t.seconds:.0f} s)"
                  + (f". **At the edge of its grid: {', '.join(t.at_grid_edge)}** (the best value may lie beyond it)"
                     if t.at_grid_edge else ""), "",
                  "| " + " | ".join(keys) + " | pos RMSE (m) |", "|" + "---:|" * (len(keys) + 1)]
        for p in t.points:
            cells = [general(p[k]) for k in keys] + [fmt(p["rmse_pos_m"])]
            if all(p[k] == t.chosen[k] for k in keys):
                cells = [f"**{c}**" for c in cells]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return lines
