"""Tables of designed cases (a PCRB per case): each case's rows against their own bound, and the
learned trackers against their finite-memory bound, over training seeds and against the best
classical method on the same runs."""

from __future__ import annotations

from ..results.typed import Case, Results
from ..scenario.references import paper_value
from .flags import below
from .report_cells import fmt, fmt_se


def case_table(name: str, case: Case, ref: dict | None, ref_label: str, single_case: bool) -> list[str]:
    """One designed case: every row's errors against its own bound, then the PCRB rows."""
    lines = [f"### {case.title} (`{name}`, {case.steps} steps)", "",
             f"| method | causal | pos RMSE (m) | vel RMSE (m/s) | own bound (m) | RMSE / bound | ANEES | diverged runs | "
             f"pooled pos RMSE (m) | {ref_label}: pos RMSE (m) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for m, r in case.methods.items():
        rmse = fmt_se(r.rmse_pos_m, r.rmse_pos_se_m)
        if r.below_bound:
            rmse = f"**{rmse}** " + ("(below its bound; no Monte Carlo error recorded!)" if r.below_bound_unsure
                                     else "(below its bound!)")
        causal = "yes" if r.causal else "no (looks ahead)"
        lines.append(f"| {m} | {causal} | {rmse} | {fmt(r.rmse_vel_mps, 3)} | {fmt(r.bound.pos_m)} ({r.bound.which}) | "
                     f"{fmt(r.bound.over)} | {fmt(r.anees)} | {'-' if r.diverged_runs is None else r.diverged_runs} / "
                     f"{r.runs} | {fmt(r.rmse_pos_pooled_m)} | {fmt(paper_value(ref, name, m, single_case))} |")
    p = case.pcrb
    lines.append(f"| PCRB filtering | | {fmt(p.pos_m)} | {fmt(p.vel_mps, 3)} | | | | | | |")
    lines.append(f"| PCRB smoothing | | {fmt(p.smoothing_pos_m)} | {fmt(p.smoothing_vel_mps, 3)} | | | | | | |")
    lines.append(f"| PCRB filtering, q = 0 (floor) | | {fmt(p.q0_pos_m)} | | | | | | | |")
    return lines


def _wide_head(lead: dict[str, str], names, per_case: dict[str, str]) -> list[str]:
    """Header and separator of a table with the ``lead`` columns, then the ``per_case`` columns
    for every case (column label -> markdown alignment, e.g. ``---:``)."""
    cols = {**lead, **{f"{c}: {label}": a for c in names for label, a in per_case.items()}}
    return ["| " + " | ".join(cols) + " |", "|" + "".join(f"{a}|" for a in cols.values())]


def learned_tables(res: Results | dict) -> list[str]:
    """Learned trackers against their finite-memory bounds, over training seeds, and against the
    best classical method on the same runs (empty without learned methods)."""
    results = Results.of(res)
    cases = results.cases
    names = list(cases)
    first = next(iter(cases.values()))
    learned = [m for m, r in first.methods.items() if r.memory is not None]
    lines = []
    if learned:
        lines += ["## Learned trackers against their finite-memory bound", "",
                  "The filtering PCRB of only the scans each estimate reads, with the training states' spread as "
                  "prior (`memory_bound_pos_m` below): the best any network of that shape could do.", "",
                  *_wide_head({"method": "---", "scans read": "---:"}, names,
                              {"bound (m)": "---:", "RMSE / bound": "---:", "MSE / bound^2": "---:"})]
        for m in learned:
            cells = []
            for c in names:
                mem = cases[c].methods[m].memory
                mse = f"{mem.mse_ratio:.2f} +- {mem.mse_ratio_se:.2f}"
                cells += [fmt(mem.pos_m), fmt(mem.over), f"**{mse}** (below!)" if mem.below else mse]
            lines.append(f"| {m} | {first.methods[m].memory.scans} | " + " | ".join(cells) + " |")
        flagged = [f for f in below(results, "memory") if f.method in learned]
        lines += ["", "MSE / bound^2: mean over runs of the run's mean squared position error over the bound's mean "
                  "square, +- its standard error; flagged when it is under 1 beyond its Monte Carlo error (the "
                  "one-sided 97.5 % Student-t bound of the mean is under 1).", "",
                  ("**Below the finite-memory bound: " + "; ".join(f.entry() for f in flagged) + ". The bound's prior "
                   "is the spread of the training states; a flight at the centre of what the network learned (e.g. no "
                   "acceleration, where the training tracks have a little) can sit below it, so compare with the q = 0 "
                   "floor above; otherwise it is a bug or test tracks the training set held, to investigate.**")
                  if flagged else "No learned tracker is below its finite-memory bound.", ""]
    if first.seed_groups:
        lines += ["## Learned trackers over training seeds", "",
                  "Each seed is its own row above (`NAME [seed k]`); here their mean, with the spread (min-max) "
                  "over seeds, and the mean ratio to the filtering PCRB and to the finite-memory bound.", "",
                  *_wide_head({"method": "---", "seeds": "---:"}, names,
                              {"pos RMSE (m)": "---:", "/ PCRB": "---:", "/ memory bound": "---:"})]
        for base, g in first.seed_groups.items():
            cells = []
            for c in names:
                e = cases[c].seed_groups[base]
                st = e.rmse_pos_m
                cells += [f"{st.mean:.2f} ({st.min:.2f}-{st.max:.2f})", fmt(e.over_bound.mean),
                          fmt(e.over_memory_bound.mean) if e.over_memory_bound is not None else "-"]
            lines.append(f"| {base} | {g.seeds} | " + " | ".join(cells) + " |")
        lines.append("")
    if first.comparisons:
        lines += ["## Learned trackers against the best classical method, on the same runs", "",
                  "Margin = mean over runs of (classical - learned) per-run position RMSE after the warm-up, in m "
                  "(positive: the learned tracker is better; a seed group counts as the mean of its seeds per run), "
                  "+- its Monte Carlo standard error.", "",
                  *_wide_head({"learned": "---"}, names, {"best classical": "---", "margin (m)": "---:"})]
        for i, comp in enumerate(first.comparisons):
            cells = []
            for c in names:
                k = cases[c].comparisons[i]
                cells += [k.classical, f"{k.margin_m:+.2f} +- {k.se_m:.2f}"]
            lines.append(f"| {comp.learned} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines
