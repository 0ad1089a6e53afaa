"""Tables of cases with several targets or tracks: position RMSE overall and per target, OSPA,
GOSPA and its parts, cardinality, identity (in older records label) switches, swaps and losses,
trajectory GOSPA, track-level figures, velocity RMSE and NEES per target (the paper's beside),
and a study's sweep."""

from __future__ import annotations

import numpy as np

from ..results.paired import comparison_lines
from ..results.result_rows import RUN_QUANTILES, MethodRow
from ..results.typed import Case, Results
from ..scenario.references import paper_seconds
from .report_cells import SWEEP_LABELS, fmt, fmt_se, space_mark, start_label, starts, switch_column


def case_heading(name: str, case: Case) -> str:
    """A multi-target case's heading: a study's Pd, clutter and spacing, or its targets' lives."""
    if case.study is not None:
        st = case.study
        spacing = f", spacing {st.spacing_m:g} m" if st.formation else ""
        return (f"### {case.title} (`{name}`: Pd {st.pd}, {st.clutter_per_scan:g} clutter per "
                f"{st.clutter_list} per scan{spacing})")
    lives = ", ".join(f"{t.name} scans {t.first_scan}-{t.end_scan - 1}" for t in case.lives)
    return f"### {case.title} (`{name}`, {case.steps} steps{': ' + lives if lives else ''})"


def multi_target_tables(res: Results | dict, timing: dict | None, label: str) -> list[str]:
    """Per multi-target case: position RMSE (overall and per target), OSPA, GOSPA and its parts,
    cardinality error, switches (:func:`~.report_cells.switch_column`), swaps, the loss rule,
    trajectory GOSPA and run time (the paper's beside). Every RMSE, OSPA and GOSPA cell carries its standard error over runs where the results hold it."""
    results = Results.of(res)
    lines = []
    for name, case in results.cases.items():
        rows = case.methods
        if not any(r.sets is not None for r in rows.values()):
            continue
        key = case.study.reference_key if case.study else None
        paper = timing is not None and key is not None
        switch_head, switches = switch_column(rows)
        lines += [case_heading(name, case), *overview_table(results, case), "",
                  "| method | reads | pos RMSE (m) | pos RMSE, all scans (m) | per target (m) | per target, assigned (m) | "
                  f"OSPA (m) | GOSPA (m) ± s.e.: % localisation / missed / false | mean abs. cardinality error | {switch_head} | "
                  "swap prob. | loss prob. | s / run |" + (f" {label}: s / run |" if paper else ""),
                  "|---|---|" + "---:|" * 2 + "---|---|" + "---:|" * 7 + ("---:|" if paper else "")]
        for m, r in rows.items():
            per = " / ".join(f"{v:.0f}" for v in (r.rmse_pos_per_target_m or [r.rmse_pos_m]))  # one target: its RMSE
            rmse = fmt_se(r.rmse_pos_m, r.rmse_pos_se_m, 1)
            s = r.sets
            if s is None:  # a bound's row: its RMSE, no tracks
                lines.append(f"| {m} | {r.bound.which} bound{starts(r)} | {rmse} | "
                             f"{fmt(r.rmse_pos_all_scans_m, 1)} | {per} |" + " - |" * (8 + paper))
                continue
            assigned = " / ".join("-" if v is None else f"{v:.0f}" for v in s.rmse_pos_assigned_per_target_m)
            split = (f"{fmt_se(s.gospa_m, s.gospa_se_m, 1)}: " + " / ".join(
                f"{100 * share:.0f}" for share in (s.gospa_localisation_share, s.gospa_missed_share, s.gospa_false_share)))
            line = (f"| {m} | {_reads(results, m, r)} | {rmse} | "
                    f"{fmt(r.rmse_pos_all_scans_m, 1)} | {per} | {assigned} | {fmt_se(s.ospa_m, s.ospa_se_m, 1)} | "
                    f"{split} | {fmt(s.cardinality_mean_abs_error, 3)} | {fmt(switches(s), 2)} | "
                    f"{fmt(r.swap_probability, 3)} | {fmt(r.loss_probability, 3)} | {fmt(r.seconds_per_run, 3)} |")
            if paper:
                line += f" {fmt(paper_seconds(timing, m, key))} |"
            lines.append(line)
        gaps = {m: r.max_duality_gap for m, r in rows.items() if r.max_duality_gap is not None}
        if gaps:
            lines += ["", "Largest duality gap of the relaxed assignments: "
                      + ", ".join(f"{m} {v:.3g} nats" for m, v in gaps.items()) + "."]
        lines += comparison_lines(case.set_comparisons)
        lines += run_spread_table(rows, results.mc_runs)
        lines += trajectory_table(rows, results.mc_runs)
        if case.pcrb is not None:
            lines += ["", f"PCRB (filtering, per target from its birth, clean streams): {fmt(case.pcrb.pos_m)} m."]
        lines += track_table(rows, results.settings.dt_s, "CLEAR MOT" in results.definitions.get("label_switches_per_run", ""),
                             {m: results.settings.methods[m].reads for m in rows if m in results.settings.methods})
        lines += ["", f"![OSPA, cardinality and RMSE vs time]({name}_set_metrics.png)", ""]
    return lines


def space_note(res: Results | dict) -> list[str]:
    """A paragraph naming the rows scored in a measurement space (empty without them)."""
    rows = sorted({m for _, m, r in Results.of(res).rows() if r.space is not None})
    if not rows:
        return []
    return [f"**Rows marked [pair ...: range, range-rate] ({', '.join(rows)}) are scored in that pair's bistatic plane: "
            "their position RMSE, OSPA and GOSPA are on bistatic range alone (one axis, m), their velocity figures on "
            "range-rate. Compare them with each other, not with Cartesian rows.** (`space` in results.json; the section "
            "\"Rows scored in a bistatic plane\" below.)", ""]


def _reads(results: Results, m: str, r: MethodRow) -> str:
    """What a row reads (and its lists), and how its tracks start where it is not its own initiator."""
    how = results.settings.methods.get(m)
    reads = "-" if how is None or how.reads is None else how.reads + (f", {how.lists}" if how.lists else "")
    return f"{reads}{starts(r)}{space_mark(r)}"


def overview_table(results: Results, case: Case) -> list[str]:
    """Every row of a case whose rows keep tracks in one table: GOSPA and its parts, OSPA, the
    matched tracks' position RMSE (each ± its standard error over the runs), confirmed and false
    tracks, track loss, switches (:func:`~.report_cells.switch_column`), time to the first track
    and run time. Empty where no row reports tracks (the tables below hold the rest)."""
    rows = case.methods
    if not any(r.tracks is not None for r in rows.values()):
        return []
    dt = results.settings.dt_s
    switch_head, switches = switch_column(rows)
    lines = ["", f"Every row in one table ({results.mc_runs} runs; ± the standard error over the runs; the tables "
             "below break each column down):", "",
             "| method | reads | GOSPA (m) ± s.e. | median run's GOSPA (m) | % localisation / missed / false | "
             "OSPA (m) ± s.e. | pos RMSE, matched (m) ± s.e. | confirmed tracks / target | false tracks / run | track loss prob. | "
             f"{switch_head} | first track after birth (s) | s / run |",
             "|---|---|" + "---:|" * 2 + "---|" + "---:|" * 8]
    for m, r in rows.items():
        s, t = r.sets, r.tracks
        parts = "-" if s is None else " / ".join(f"{100 * v:.0f}" for v in (
            s.gospa_localisation_share, s.gospa_missed_share, s.gospa_false_share))
        first = None if t is None or t.scans_to_first_track is None else t.scans_to_first_track * dt
        reads = f"{r.bound.which} bound{starts(r)}" if s is None and r.bound is not None else _reads(results, m, r)
        lines.append(f"| {m} | {reads} | {fmt_se(s and s.gospa_m, s and s.gospa_se_m, 1)} | "
                     f"{fmt(s and s.gospa_median_run_m, 1)} | {parts} | "
                     f"{fmt_se(s and s.ospa_m, s and s.ospa_se_m, 1)} | {fmt_se(r.rmse_pos_m, r.rmse_pos_se_m, 1)} | "
                     f"{fmt(t and t.confirmed_tracks_per_target, 2)} | {fmt(t and t.false_tracks_per_run, 2)} | "
                     f"{fmt(t and t.track_loss_probability, 2)} | {fmt(switches(s), 2)} | "
                     f"{fmt(first, 2)} | {fmt(r.seconds_per_run, 3)} |")
    return lines


def run_spread_table(rows: dict[str, MethodRow], runs: int) -> list[str]:
    """Each run's GOSPA over the ``runs`` runs at :data:`~pmsr_nn.harness.results.result_rows.RUN_QUANTILES`,
    per row that holds them (empty for none): a mean far above the median comes from a few runs,
    and this says how few."""
    have = {m: r.sets.gospa_run_quantiles_m for m, r in rows.items()
            if r.sets is not None and r.sets.gospa_run_quantiles_m is not None}
    if not have:
        return []
    head = " | ".join("worst" if q == 1.0 else f"{100 * q:g} %" for q in RUN_QUANTILES)
    lines = ["", f"Each run's GOSPA (m) over the {runs} runs (the p-th root of the run's mean GOSPA^p; linear "
                 "interpolation between the runs):", "", f"| method | {head} |", "|---|" + "---:|" * len(RUN_QUANTILES)]
    lines += [f"| {m} | " + " | ".join(f"{v:.1f}" for v in q) + " |" for m, q in have.items()]
    return lines


def trajectory_table(rows: dict[str, MethodRow], runs: int) -> list[str]:
    """Trajectory GOSPA with its switching cost, per row that holds it (empty for none, e.g.
    results recorded before it was kept): each row's value ± its standard error, its parts and
    the switches of its optimal assignment."""
    have = {m: r.sets for m, r in rows.items() if r.sets is not None and r.sets.tgospa_m is not None}
    if not have:
        return []
    gamma = next(iter(have.values())).tgospa_gamma_m
    lines = ["", f"Trajectory GOSPA (García-Fernández et al. 2020; switching cost gamma = {gamma:g} m, the cut-off; "
                 "per set scan, like GOSPA, which it equals without the switching cost; the LP relaxation, integral "
                 "and so the metric's own value in the runs counted):", "",
             "| method | trajectory GOSPA (m) ± s.e. | % localisation / missed / false / switching | switches / run | "
             "runs integral |", "|---|---:|---|---:|---:|"]
    for m, s in have.items():
        parts = " / ".join(f"{100 * v:.0f}" for v in (s.tgospa_localisation_share, s.tgospa_missed_share,
                                                     s.tgospa_false_share, s.tgospa_switching_share))
        lines.append(f"| {m} | {fmt_se(s.tgospa_m, s.tgospa_se_m, 1)} | {parts} | {fmt(s.tgospa_switches_per_run, 2)} | "
                     f"{s.tgospa_integral_runs} of {runs} |")
    return lines


def track_table(rows: dict[str, MethodRow], dt: float, persistent: bool = False,
                reads: dict[str, str | None] | None = None) -> list[str]:
    """Track-level figures of every row (``dt`` the scan interval in s; ``persistent``: counted on
    the persistent mapping of tracks to targets, else, in records made before it, on each scan's
    OSPA assignment; ``reads``: the product each row reads, named where a row starts its own tracks)."""
    have = {m: r for m, r in rows.items() if r.tracks is not None}
    if not have:
        return []
    how = ("mapped to the living targets as CLEAR MOT maps them (a track stays on its target while within the cut-off "
           "c; the others by each scan's OSPA assignment)" if persistent else
           "matched to the living targets scan by scan (OSPA assignment, cut-off c)")
    lines = ["", f"Tracks, {how} over each target's whole life; oracle rows are handed each target's birth:", "",
             "| method | tracks start | confirmed tracks / target | false tracks / run | missed-target fraction | "
             "first track after birth (s) | track loss prob. | fragmentations / run |",
             "|---|---|" + "---:|" * 6]
    for m, r in have.items():
        t = r.tracks
        first = t.scans_to_first_track
        lines.append(f"| {m} | {start_label(r, (reads or {}).get(m))} | {fmt(t.confirmed_tracks_per_target, 2)} | "
                     f"{fmt(t.false_tracks_per_run, 2)} | {fmt(t.missed_target_fraction, 4)} | "
                     f"{fmt(None if first is None else first * dt, 2)} | {fmt(t.track_loss_probability, 3)} | "
                     f"{fmt(t.fragmentations_per_run, 2)} |")
    return lines


def per_target_tables(res: Results | dict, label: str) -> list[str]:
    """Per multi-target case: velocity RMSE and NEES per target of every method, the paper's
    per-target tables beside them where the scenario names them (``reference.per_target``)."""
    results = Results.of(res)
    per = results.reference.get("per_target") or {}
    names = per.get("methods", {})
    lines = []
    for name, case in results.cases.items():
        rows = {m: r for m, r in case.methods.items() if r.rmse_vel_per_target_mps is not None}
        if not rows:
            continue
        targets = case.targets
        vel_ref = {m: per["velocity_rmse"][k] for m, k in names.items() if k in per.get("velocity_rmse", {})}
        head = ["target", *(f"{m}{space_mark(r)} (m/s)" for m, r in rows.items()), *(f"{label}: {m} (m/s)" for m in vel_ref)]
        lines += [f"### Velocity RMSE per target, `{name}`", "", "| " + " | ".join(head) + " |",
                  "|---|" + "---:|" * (len(head) - 1)]
        for t, tname in enumerate(targets):
            cells = [fmt(r.rmse_vel_per_target_mps[t]) for r in rows.values()]
            cells += [fmt(v[t]) if t < len(v) else "-" for v in vel_ref.values()]
            lines.append(f"| {tname} | " + " | ".join(cells) + " |")
        means = [fmt(float(np.mean(r.rmse_vel_per_target_mps))) for r in rows.values()]
        means += [fmt(float(np.mean(v))) for v in vel_ref.values()]
        lines += ["| mean | " + " | ".join(means) + " |", ""]
        n = results.settings.state_dim
        # rows in a measurement space have their own state (anees in results.json, over its dimension)
        with_p = [m for m, r in rows.items() if r.anees_per_target and r.space is None]
        if not with_p or not n:
            continue
        anees_ref = per.get("anees")
        proposed = next((m for m, k in names.items() if k == "proposed"), None)
        head = ["target", *(f"{m}" for m in with_p)] + ([f"{label}: {proposed}"] if anees_ref and proposed else [])
        lines += [f"### NEES per target (not divided by the state dimension {n}: the paper's convention; {n} = "
                  f"consistent), `{name}`", "", "| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
        for t, tname in enumerate(targets):
            cells = [fmt(n * rows[m].anees_per_target[t]) for m in with_p]
            if anees_ref and proposed:
                cells.append(fmt(anees_ref[t]) if t < len(anees_ref) else "-")
            lines.append(f"| {tname} | " + " | ".join(cells) + " |")
        means = [fmt(n * float(np.mean(rows[m].anees_per_target))) for m in with_p]
        if anees_ref and proposed:
            means.append(fmt(float(np.mean(anees_ref))))
        lines += ["| mean | " + " | ".join(means) + " |", ""]
    if per:
        lines += [f"Columns marked *{label}* are the paper's tables (`{per.get('velocity_rmse_key')}`, "
                  f"`{per.get('anees_key')}`), for reference only; method names map as {names}.", ""]
    return lines


def sweep_table(res: Results | dict, timing: dict | None, label: str) -> list[str]:
    """One row per case: RMSE, OSPA, loss and time of every method; the paper's times for the
    methods it timed (matched by name); and the time ratio of every P-MSJPDA variant to the first
    S-MSJPDA."""
    results = Results.of(res)
    sweep = results.settings.sweep
    cases = list(results.cases.values())
    first = cases[0].methods
    methods = list(first)
    timed = [m for m in methods if timing and m in timing]
    s_ref = next((m for m in methods if first[m].kind == "s_msjpda"), None)
    parallel = [m for m in methods if first[m].kind == "p_msjpda"] if s_ref else []
    paper_ratio = "P-MSJPDA" in timed and "S-MSJPDA" in timed
    head = "| " + SWEEP_LABELS[sweep] + " | " + " | ".join(f"{m}: RMSE (m) | {m}: OSPA (m) | {m}: loss | {m}: s/run"
                                                          for m in methods)
    head += "".join(f" | {label}: {m} s/run" for m in timed)
    head += "".join(f" | {m} / {s_ref} time" for m in parallel)
    head += f" | {label}: P/S time |" if paper_ratio else " |"
    lines = [head, "|" + "---:|" * (head.count("|") - 1)]
    for case in cases:
        r = case.methods
        key = case.study.reference_key
        row = f"| {getattr(case.study, sweep):g} | " + " | ".join(
            f"{fmt_se(r[m].rmse_pos_m, r[m].rmse_pos_se_m, 1)} | "
            f"{fmt_se(r[m].sets.ospa_m, r[m].sets.ospa_se_m, 1) if r[m].sets else '-'} | "
            f"{fmt(r[m].loss_probability, 3)} | {fmt(r[m].seconds_per_run, 3)}" for m in methods)
        row += "".join(f" | {fmt(paper_seconds(timing, m, key))}" for m in timed)
        row += "".join(f" | {r[m].seconds_per_run / r[s_ref].seconds_per_run:.1f}" for m in parallel)
        if paper_ratio:
            p, s = (paper_seconds(timing, m, key) for m in ("P-MSJPDA", "S-MSJPDA"))
            row += f" | {fmt(p / s if p and s else None, 1)}"
        lines.append(row + " |")
    return lines + [""]
