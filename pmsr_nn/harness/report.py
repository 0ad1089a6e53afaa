"""``report.md`` and PNG figures from a ``results.json`` dict (and the example run's estimates).

The paper's numbers, where the scenario names a reference table, are printed in their own
column labelled as the paper's; they are read from the reference file and never enter a figure
of ours.
"""

from __future__ import annotations

import json
import textwrap
import warnings
from pathlib import Path

import numpy as np

from ..errors import ConfigError


def reference_table(path: Path, dotted: str) -> dict:
    """The entry ``dotted`` (``a.b.c``) of the JSON reference file at ``path``; a key that itself
    holds dots (``table_pd_0.8``) is matched whole, longest first."""
    try:
        node = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"reference file {path}: {exc}") from None
    parts = dotted.split(".")
    while parts:
        for n in range(len(parts), 0, -1):
            key = ".".join(parts[:n])
            if isinstance(node, dict) and key in node:
                node, parts = node[key], parts[n:]
                break
        else:
            raise ConfigError(f"reference file {path} has no entry {dotted!r}")
    return node


def paper_value(ref: dict | None, case: str, method: str, single_case: bool):
    if not ref:
        return None
    row = ref if single_case else ref.get(case, {})
    v = row.get(method) if isinstance(row, dict) else None
    return v if isinstance(v, (int, float)) else None


def _span(values) -> str:
    lo, hi = min(values), max(values)
    return f"{lo:.2f}" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}-{hi:.2f}"


def _f(v, digits=2) -> str:
    if v is None:
        return "-"
    if isinstance(v, float) and not np.isfinite(v):
        return str(v)
    return f"{v:.{digits}f}"


def case_table(name: str, case: dict, ref: dict | None, ref_label: str, single_case: bool) -> list[str]:
    lines = [f"### {case['title']} (`{name}`, {case['steps']} steps)", "",
             f"| method | causal | pos RMSE (m) | vel RMSE (m/s) | own bound (m) | RMSE / bound | ANEES | diverged runs | "
             f"pooled pos RMSE (m) | {ref_label}: pos RMSE (m) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for m, r in case["methods"].items():
        rmse = _f(r["rmse_pos_m"])
        if r["below_bound"]:
            rmse = f"**{rmse}** (below its bound!)"
        causal = "yes" if r["causal"] else "no (looks ahead)"
        lines.append(f"| {m} | {causal} | {rmse} | {_f(r['rmse_vel_mps'], 3)} | {_f(r['bound_pos_m'])} ({r['bound']}) | "
                     f"{_f(r['over_bound'])} | {_f(r['anees'])} | {r.get('diverged_runs', '-')} / {r['runs']} | "
                     f"{_f(r['rmse_pos_pooled_m'])} | {_f(paper_value(ref, name, m, single_case))} |")
    p = case["pcrb"]
    lines.append(f"| PCRB filtering | | {_f(p['pos_m'])} | {_f(p['vel_mps'], 3)} | | | | | | |")
    lines.append(f"| PCRB smoothing | | {_f(p['smoothing_pos_m'])} | {_f(p['smoothing_vel_mps'], 3)} | | | | | | |")
    lines.append(f"| PCRB filtering, q = 0 (floor) | | {_f(p['q0_pos_m'])} | | | | | | | |")
    return lines


def summary_table(res: dict, ref: dict | None, ref_label: str, single_case: bool) -> list[str]:
    """Methods x cases, ours beside the paper's (the layout of the MDFNN paper's Table 6)."""
    names = list(res["cases"])
    head = "| method | " + " | ".join(f"{c} ours | {c} {ref_label}" if ref else f"{c}" for c in names) + " |"
    lines = [head, "|---|" + "---:|" * (len(names) * (2 if ref else 1))]
    methods = list(dict.fromkeys(m for c in res["cases"].values() for m in c["methods"]))  # a case may run some only
    for m in methods:
        cells = []
        for c in names:
            r = res["cases"][c]["methods"].get(m)
            if r is None:  # not run in this case
                cells += ["-"] + (["-"] if ref else [])
                continue
            v = _f(r["rmse_pos_m"])
            cells.append(f"**{v}**" if r.get("below_bound") else v)
            if ref:
                cells.append(_f(paper_value(ref, c, m, single_case)))
        first = next(c["methods"][m] for c in res["cases"].values() if m in c["methods"])
        lines.append(f"| {m}{space_mark(first)} | " + " | ".join(cells) + " |")
    if any(c.get("pcrb") is None for c in res["cases"].values()):
        return lines
    for key, label in (("pos_m", "PCRB (filtering, per trajectory)"), ("q0_pos_m", "PCRB with q = 0 (floor)")):
        cells = [cell for c in names for cell in [_f(res["cases"][c]["pcrb"][key])] + (["-"] if ref else [])]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def _wide_head(lead: dict[str, str], names, per_case: dict[str, str]) -> list[str]:
    """Header and separator of a table with the ``lead`` columns, then the ``per_case`` columns
    for every case (column label -> markdown alignment, e.g. ``---:``)."""
    cols = {**lead, **{f"{c}: {label}": a for c in names for label, a in per_case.items()}}
    return ["| " + " | ".join(cols) + " |", "|" + "".join(f"{a}|" for a in cols.values())]


def learned_tables(res: dict) -> list[str]:
    """Learned trackers against their finite-memory bounds, over training seeds, and against the
    best classical method on the same runs (empty without learned methods)."""
    cases = res["cases"]
    names = list(cases)
    first = next(iter(cases.values()))
    learned = [m for m, r in first["methods"].items() if "memory_bound_pos_m" in r]
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
                r = cases[c]["methods"][m]
                mse = f"{r['mse_over_memory_bound']:.2f} +- {r['mse_over_memory_bound_se']:.2f}"
                cells += [_f(r["memory_bound_pos_m"]), _f(r["over_memory_bound"]),
                          f"**{mse}** (below!)" if r["below_memory_bound"] else mse]
            lines.append(f"| {m} | {first['methods'][m]['memory_scans']} | " + " | ".join(cells) + " |")
        below = [f"{m} on {c}" for c in names for m in learned if cases[c]["methods"][m]["below_memory_bound"]]
        lines += ["", "MSE / bound^2: mean over runs of the run's mean squared position error over the bound's mean "
                  "square, +- its standard error; flagged when more than two standard errors below 1.", "",
                  ("**Below the finite-memory bound: " + ", ".join(below) + ". The bound's prior is the spread of the "
                   "training states; a flight at the centre of what the network learned (e.g. no acceleration, where "
                   "the training tracks have a little) can sit below it, so compare with the q = 0 floor above; "
                   "otherwise it is a bug or test tracks the training set held, to investigate.**")
                  if below else "No learned tracker is below its finite-memory bound.", ""]
    groups = first.get("seed_groups", {})
    if groups:
        lines += ["## Learned trackers over training seeds", "",
                  "Each seed is its own row above (`NAME [seed k]`); here their mean, with the spread (min-max) "
                  "over seeds, and the mean ratio to the filtering PCRB and to the finite-memory bound.", "",
                  *_wide_head({"method": "---", "seeds": "---:"}, names,
                              {"pos RMSE (m)": "---:", "/ PCRB": "---:", "/ memory bound": "---:"})]
        for base, g in groups.items():
            cells = []
            for c in names:
                e = cases[c]["seed_groups"][base]
                st = e["rmse_pos_m"]
                cells += [f"{st['mean']:.2f} ({st['min']:.2f}-{st['max']:.2f})", _f(e["over_bound"]["mean"]),
                          _f(e["over_memory_bound"]["mean"]) if "over_memory_bound" in e else "-"]
            lines.append(f"| {base} | {g['seeds']} | " + " | ".join(cells) + " |")
        lines.append("")
    if first.get("comparisons"):
        lines += ["## Learned trackers against the best classical method, on the same runs", "",
                  "Margin = mean over runs of (classical - learned) per-run position RMSE after the warm-up, in m "
                  "(positive: the learned tracker is better; a seed group counts as the mean of its seeds per run), "
                  "+- its Monte Carlo standard error.", "",
                  *_wide_head({"learned": "---"}, names, {"best classical": "---", "margin (m)": "---:"})]
        for i, comp in enumerate(first["comparisons"]):
            cells = []
            for c in names:
                k = cases[c]["comparisons"][i]
                cells += [k["classical"], f"{k['margin_m']:+.2f} +- {k['se_m']:.2f}"]
            lines.append(f"| {comp['learned']} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def timing_table(res: dict, ref_timing: dict | None, ref_label: str) -> list[str]:
    cases = list(res["cases"].values())
    methods = list(dict.fromkeys(m for c in cases for m in c["methods"]))  # a case may run some methods only
    mc = res["mc_runs"]
    lines = [f"| method | ms per run (median over cases) | ms for {mc} runs of one case | {ref_label}: ms |",
             "|---|---:|---:|---:|"]
    for m in methods:
        ran = [c["methods"][m]["seconds_per_run"] for c in cases if m in c["methods"]]
        if ran[0] is None:  # a bound's row: nothing was run
            continue
        s = float(np.median(ran))
        ref = ref_timing.get(m) if ref_timing else None
        ref = ref if isinstance(ref, (int, float)) else None  # a study's per-case times go in its own table
        lines.append(f"| {m} | {1e3 * s:.2f} | {1e3 * s * mc:.0f} | {_f(ref, 1)} |")
    steps = cases[0]["steps"]
    lines += ["", f"Wall-clock of whole calls on blocks of {res['settings']['block_runs']} runs x {steps} scans (all runs "
              "of a block at once, all targets), divided by the runs; learned trackers include windowing and splicing."]
    if ref_timing and ref_timing.get("_note"):
        lines.append(f"{ref_label.capitalize()}: {ref_timing['_note']}.")
    return lines


def _g(v) -> str:
    return f"{v:g}" if isinstance(v, (int, float)) else str(v)


def tuning_tables(res: dict) -> list[str]:
    """One table per method with tuned options: every grid point's position RMSE on the tuning
    tracks, the chosen point in bold (empty when no option was tuned)."""
    tuned = {m: s["tuning"] for m, s in res["settings"]["methods"].items() if "tuning" in s}
    if not tuned:
        return []
    first = next(iter(tuned.values()))
    lines = ["## Tuned options", "",
             f"Options marked `tuned` were chosen by a grid search on {first['tracks']} tracks of {first['steps']} steps "
             f"drawn from the training recipe `{Path(first['recipe']).name}` (seed {first['seed']}, apart from the "
             "evaluation's draws), measured with this scenario's noise: the point with the lowest position RMSE after "
             f"the warm-up ({first['warmup_steps']} steps, Eq. 31) is used (bold).", ""]
    for name, t in tuned.items():
        keys = t["options"]
        chosen = ", ".join(f"{k} = {_g(t['chosen'][k])}" for k in keys)
        lines += [f"**{name}**: {chosen} (RMSE {_f(t['rmse_pos_m'])} m on the tuning tracks; {len(t['points'])} points, "
                  f"{t['seconds']:.0f} s)"
                  + (f". **At the edge of its grid: {', '.join(t['at_grid_edge'])}** (the best value may lie beyond it)"
                     if t.get("at_grid_edge") else ""), "",
                  "| " + " | ".join(keys) + " | pos RMSE (m) |", "|" + "---:|" * (len(keys) + 1)]
        for p in t["points"]:
            cells = [_g(p[k]) for k in keys] + [_f(p["rmse_pos_m"])]
            if all(p[k] == t["chosen"][k] for k in keys):
                cells = [f"**{c}**" for c in cells]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return lines


SWEEP_LABELS = {"pd": "detection probability Pd", "clutter_per_scan": "clutter points per sensor per scan",
                "spacing_m": "spacing of the formation (m)"}


def _paper_seconds(timing: dict | None, method: str, key: str | None):
    """A study's run time of ``method`` for the case keyed ``key`` in the paper's table (seconds)."""
    if not timing or key is None:
        return None
    v = timing.get(method, {})
    v = v.get(key) if isinstance(v, dict) else None
    return v if isinstance(v, (int, float)) else None


def _case_heading(name: str, case: dict) -> str:
    if "pd" in case:  # a multi-target study's case
        spacing = f", spacing {case['spacing_m']:g} m" if case.get("formation", True) else ""
        return (f"### {case['title']} (`{name}`: Pd {case['pd']}, {case['clutter_per_scan']:g} clutter per "
                f"{case.get('clutter_list', 'sensor')} per scan{spacing})")
    lives = ", ".join(f"{t['name']} scans {t['first_scan']}-{t['end_scan'] - 1}" for t in case.get("lives", []))
    return f"### {case['title']} (`{name}`, {case['steps']} steps{': ' + lives if lives else ''})"


def multi_target_tables(res: dict, timing: dict | None, label: str) -> list[str]:
    """Per multi-target case: position RMSE (overall and per target), OSPA, GOSPA and its parts,
    cardinality error, label switches, swaps, the loss rule, and run time (the paper's beside)."""
    lines = []
    for name, case in res["cases"].items():
        rows = case["methods"]
        if not any("ospa_m" in r for r in rows.values()):
            continue
        key = case.get("reference_key")
        paper = timing is not None and key is not None
        lines += [_case_heading(name, case), "",
                  "| method | reads | pos RMSE (m) | pos RMSE, all scans (m) | per target (m) | per target, assigned (m) | "
                  "OSPA (m) | GOSPA (m) ± s.e.: % localisation / missed / false | mean abs. cardinality error | label switches / run | "
                  "swap prob. | loss prob. | s / run |" + (f" {label}: s / run |" if paper else ""),
                  "|---|---|" + "---:|" * 2 + "---|---|" + "---:|" * 7 + ("---:|" if paper else "")]
        for m, r in rows.items():
            per = " / ".join(f"{v:.0f}" for v in r.get("rmse_pos_per_target_m", [r["rmse_pos_m"]]))  # one target: its RMSE
            if "ospa_m" not in r:  # a bound's row: its RMSE, no tracks
                lines.append(f"| {m} | {r['bound']} bound{_starts(r)} | {_f(r['rmse_pos_m'], 1)} | "
                             f"{_f(r['rmse_pos_all_scans_m'], 1)} | {per} |" + " - |" * (8 + paper))
                continue
            assigned = " / ".join("-" if v is None else f"{v:.0f}" for v in r["rmse_pos_assigned_per_target_m"])
            se = f" ± {r['gospa_se_m']:.1f}" if r.get("gospa_se_m") is not None else ""
            split = (f"{_f(r['gospa_m'], 1)}{se}: " + " / ".join(f"{100 * r[f'gospa_{p}_share']:.0f}"
                                                              for p in ("localisation", "missed", "false")))
            line = (f"| {m} | {res['settings']['methods'][m].get('reads', '-')}{_starts(r)}{space_mark(r)} | {_f(r['rmse_pos_m'], 1)} | "
                    f"{_f(r['rmse_pos_all_scans_m'], 1)} | {per} | {assigned} | {_f(r['ospa_m'], 1)} | {split} | "
                    f"{_f(r['cardinality_mean_abs_error'], 3)} | {_f(r['label_switches_per_run'], 2)} | "
                    f"{_f(r.get('swap_probability'), 3)} | {_f(r.get('loss_probability'), 3)} | {_f(r['seconds_per_run'], 3)} |")
            if paper:
                line += f" {_f(_paper_seconds(timing, m, key))} |"
            lines.append(line)
        gaps = {m: r["max_duality_gap"] for m, r in rows.items() if "max_duality_gap" in r}
        if gaps:
            lines += ["", "Largest duality gap of the relaxed assignments: "
                      + ", ".join(f"{m} {v:.3g} nats" for m, v in gaps.items()) + "."]
        if "pcrb" in case and case["pcrb"] is not None:
            lines += ["", f"PCRB (filtering, per target from its birth, clean streams): {_f(case['pcrb']['pos_m'])} m."]
        lines += track_table(rows, res["settings"].get("dt_s", 1.0))
        lines += ["", f"![OSPA, cardinality and RMSE vs time]({name}_set_metrics.png)", ""]
    return lines


def space_mark(row: dict) -> str:
    """`` [pair 0: range, range-rate]`` for a row scored in a measurement space (its ``space_key``),
    so that its figures are never read as Cartesian ones; empty otherwise."""
    return f" [{row['space_key']}: range, range-rate]" if row.get("space_key") else ""


def space_note(res: dict) -> list[str]:
    """A paragraph naming the rows scored in a measurement space (empty without them)."""
    rows = sorted({m for c in res["cases"].values() for m, r in c["methods"].items() if r.get("space_key")})
    if not rows:
        return []
    return [f"**Rows marked [pair ...: range, range-rate] ({', '.join(rows)}) are scored in that pair's bistatic plane: "
            "their position RMSE, OSPA and GOSPA are on bistatic range alone (one axis, m), their velocity figures on "
            "range-rate. Compare them with each other, not with Cartesian rows.** (`space` in results.json; the section "
            "\"Rows scored in a bistatic plane\" below.)", ""]


def _starts(row: dict) -> str:
    """How a row's tracks start, where it is not its own initiator: said in every row it applies to."""
    return {"oracle": " (oracle births)", "association known": " (association known)"}.get(row.get("initiation"), "")


def track_table(rows: dict, dt: float) -> list[str]:
    """Track-level figures of every row (per-scan assignment to the living targets)."""
    have = {m: r for m, r in rows.items() if "confirmed_tracks_per_target" in r}
    if not have:
        return []
    lines = ["", "Tracks, matched to the living targets scan by scan (OSPA assignment, cut-off c) over each target's "
                 "whole life; oracle rows are handed each target's birth:", "",
             "| method | tracks start | confirmed tracks / target | false tracks / run | missed-target fraction | "
             "first track after birth (s) | track loss prob. | fragmentations / run |",
             "|---|---|" + "---:|" * 6]
    for m, r in have.items():
        first = r.get("scans_to_first_track")
        lines.append(f"| {m} | {r.get('initiation', '-')} | {_f(r['confirmed_tracks_per_target'], 2)} | "
                     f"{_f(r['false_tracks_per_run'], 2)} | {_f(r['missed_target_fraction'], 4)} | "
                     f"{_f(None if first is None else first * dt, 2)} | {_f(r['track_loss_probability'], 3)} | "
                     f"{_f(r['fragmentations_per_run'], 2)} |")
    return lines


def per_target_tables(res: dict, label: str) -> list[str]:
    """Per multi-target case: velocity RMSE and ANEES per target of every method, the paper's
    per-target tables beside them where the scenario names them (``reference.per_target``)."""
    per = (res.get("reference") or {}).get("per_target") or {}
    names = per.get("methods", {})
    lines = []
    for name, case in res["cases"].items():
        rows = {m: r for m, r in case["methods"].items() if r.get("rmse_vel_per_target_mps") is not None}
        if not rows:
            continue
        targets = case["targets"]
        vel_ref = {m: per["velocity_rmse"][k] for m, k in names.items() if k in per.get("velocity_rmse", {})}
        head = ["target", *(f"{m}{space_mark(r)} (m/s)" for m, r in rows.items()), *(f"{label}: {m} (m/s)" for m in vel_ref)]
        lines += [f"### Velocity RMSE per target, `{name}`", "", "| " + " | ".join(head) + " |",
                  "|---|" + "---:|" * (len(head) - 1)]
        for t, tname in enumerate(targets):
            cells = [_f(r["rmse_vel_per_target_mps"][t]) for r in rows.values()]
            cells += [_f(v[t]) if t < len(v) else "-" for v in vel_ref.values()]
            lines.append(f"| {tname} | " + " | ".join(cells) + " |")
        means = [_f(float(np.mean(r["rmse_vel_per_target_mps"]))) for r in rows.values()]
        means += [_f(float(np.mean(v))) for v in vel_ref.values()]
        lines += ["| mean | " + " | ".join(means) + " |", ""]
        n = res["settings"].get("state_dim")
        # rows in a measurement space have their own state (anees in results.json, over its dimension)
        with_p = [m for m, r in rows.items() if r.get("anees_per_target") and not r.get("space_key")]
        if not with_p or not n:
            continue
        anees_ref = per.get("anees")
        proposed = next((m for m, k in names.items() if k == "proposed"), None)
        head = ["target", *(f"{m}" for m in with_p)] + ([f"{label}: {proposed}"] if anees_ref and proposed else [])
        lines += [f"### NEES per target (not divided by the state dimension {n}: the paper's convention; {n} = "
                  f"consistent), `{name}`", "", "| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
        for t, tname in enumerate(targets):
            cells = [_f(n * rows[m]["anees_per_target"][t]) for m in with_p]
            if anees_ref and proposed:
                cells.append(_f(anees_ref[t]) if t < len(anees_ref) else "-")
            lines.append(f"| {tname} | " + " | ".join(cells) + " |")
        means = [_f(n * float(np.mean(rows[m]["anees_per_target"]))) for m in with_p]
        if anees_ref and proposed:
            means.append(_f(float(np.mean(anees_ref))))
        lines += ["| mean | " + " | ".join(means) + " |", ""]
    if per:
        lines += [f"Columns marked *{label}* are the paper's tables (`{per.get('velocity_rmse_key')}`, "
                  f"`{per.get('anees_key')}`), for reference only; method names map as {names}.", ""]
    return lines


def sweep_table(res: dict, timing: dict | None, label: str) -> list[str]:
    """One row per case: RMSE, loss and time of every method; the paper's times for the methods it
    timed (matched by name); and the time ratio of every P-MSJPDA variant to the first S-MSJPDA."""
    sweep = res["settings"]["sweep"]
    first = next(iter(res["cases"].values()))["methods"]
    methods = list(first)
    timed = [m for m in methods if timing and m in timing]
    s_ref = next((m for m in methods if first[m]["kind"] == "s_msjpda"), None)
    parallel = [m for m in methods if first[m]["kind"] == "p_msjpda"] if s_ref else []
    paper_ratio = "P-MSJPDA" in timed and "S-MSJPDA" in timed
    head = "| " + SWEEP_LABELS[sweep] + " | " + " | ".join(f"{m}: RMSE (m) | {m}: OSPA (m) | {m}: loss | {m}: s/run"
                                                          for m in methods)
    head += "".join(f" | {label}: {m} s/run" for m in timed)
    head += "".join(f" | {m} / {s_ref} time" for m in parallel)
    head += f" | {label}: P/S time |" if paper_ratio else " |"
    lines = [head, "|" + "---:|" * (head.count("|") - 1)]
    for case in res["cases"].values():
        r = case["methods"]
        row = f"| {case[sweep]:g} | " + " | ".join(
            f"{_f(r[m]['rmse_pos_m'], 1)} | {_f(r[m]['ospa_m'], 1)} | {_f(r[m].get('loss_probability'), 3)} | "
            f"{_f(r[m]['seconds_per_run'], 3)}" for m in methods)
        row += "".join(f" | {_f(_paper_seconds(timing, m, case['reference_key']))}" for m in timed)
        row += "".join(f" | {r[m]['seconds_per_run'] / r[s_ref]['seconds_per_run']:.1f}" for m in parallel)
        if paper_ratio:
            p, s = (_paper_seconds(timing, m, case["reference_key"]) for m in ("P-MSJPDA", "S-MSJPDA"))
            row += f" | {_f(p / s if p and s else None, 1)}"
        lines.append(row + " |")
    return lines + [""]


def _setting_lines(res: dict) -> list[str]:
    """What was simulated, in one paragraph."""
    st = res["settings"]
    if "scans" in st:  # a multi-target study
        tx = ", ".join(f"({p['position_m'][0] / 1e3:g}, {p['position_m'][1] / 1e3:g}) km at {p['carrier_hz'] / 1e6:g} MHz"
                       for p in st["transmitters"])
        tr = st["methods"]
        m_best = sorted({v["m_best"] for v in tr.values() if "m_best" in v})
        mo = st.get("motion", {"model": "cv", "vertical_q": None, "truth": "sampled"})
        unit = "m^2/s^3 (PSD of continuous white acceleration)" if mo["model"] == "cv_continuous" else "m^2/s^4"
        vertical = f", vertically {mo['vertical_q']:g}" if mo.get("vertical_q") is not None else ""
        truth = "the truth flies straight lines, the same in every run" if mo["truth"] == "straight" else "the truth's"
        pooled = ("; detections pooled per receiver (single-frequency network: the illuminator of a detection is "
                  "unknown; clutter per receiver list)" if st.get("illuminator_known") is False else "")
        peers = [m for m, v in tr.items() if v.get("kind") == "stonesoup"]
        peers = (f" Stone Soup rows ({', '.join(peers)}): Stone Soup 1.9.1's EKF with its JPDA (every joint event) or "
                 "GNN, given the same Pd, clutter density and priors and our motion and bistatic models, the pairs in "
                 "turn (pmsr_nn/methods/stonesoup.py); the UKF moments and m best events are ours." if peers else "")
        rate, box = f"Doppler {st['noise']['doppler_hz']} Hz", f"Doppler {st['clutter']['doppler_hz']} Hz"
        if "range_rate_mps" in st["noise"]:  # detections of range-rate
            rate, box = f"range-rate {st['noise']['range_rate_mps']} m/s", f"range-rate {st['clutter']['range_rate_mps']} m/s"
        trackers = (f"Trackers: UKF moments, m = {', '.join(map(str, m_best)) or '-'} best events (JPDA), gate probability "
                    f"{st['tracker']['gate_probability']}, CV with q = {st['q']} {unit}{vertical} ({truth}). Loss rule: "
                    f"{st['loss']['successive_scans']} scans dummy-most-probable, or predicted range deviation > "
                    f"{st['loss']['gate_range_sd_m']:g} m.")
        if st.get("aircraft"):  # designed flights: the trackers' settings are their rows' options
            limit = "" if st.get("max_range_m") is None else f" and within {st['max_range_m'] / 1e3:g} km of bistatic range"
            trackers = (f"Truth: {len(st['aircraft'])} designed aircraft flights ({', '.join(st['aircraft'])}), each seen "
                        f"above {st['min_altitude_m']:g} m{limit}; the trackers' settings are their options (settings in "
                        "results.json).")
        return [f"{st['scans']} scans of {st['dt_s']} s, {st.get('dimensions', 2)}-D. Transmitters {tx}; receiver at "
                f"{st['receivers'][0]}. Noise: range "
                f"{st['noise']['range_m']} m, {rate}. Clutter: {st['clutter']['model']}, "
                f"uniform over range {st['clutter']['range_m']} m x {box}{pooled}. "
                f"{trackers} OSPA / GOSPA cut-off {st['set_metrics']['c_m']:g} m, order "
                f"{st['set_metrics']['p']:g}. Position RMSE = {res['definitions']['rmse_pos_m']}.{peers}", ""]
    if "rd_maps" in st and all(m.get("reads") == "rd_maps" for m in st["methods"].values()):  # maps, no measurements
        return [f"Every method reads the range-Doppler maps of the scenario's rd_maps section (each case's maps in the "
                f"track-before-detect section below); recipe `{Path(st['recipe']).name}` (dt {st['dt_s']} s, the frames). "
                f"Position RMSE = {res['definitions']['rmse_pos_m']} (warm-up {st['warmup_steps']} steps), over each "
                f"method's tracks matched to the target; OSPA / GOSPA cut-off {st['set_metrics']['c_m']:g} m, order "
                f"{st['set_metrics']['p']:g}.", ""]
    outliers = (f" ({100 * st['noise']['range_outlier_prob']:g} % of range errors with {st['noise']['range_outlier_scale']:g}x "
                "the deviation; the filters assume the nominal one)" if "range_outlier_prob" in st["noise"] else "")
    lines = [f"Noise: {st['noise']['range_m']} m, {st['noise']['range_rate_mps']} m/s, {st['noise']['azimuth_deg']} deg{outliers}; "
             f"recipe `{Path(st['recipe']).name}` ({st['variant']} variant, dt {st['dt_s']} s, q {st['q_psd']:g} m^2/s^5). "
             f"Position RMSE = {res['definitions']['rmse_pos_m']} (warm-up {st['warmup_steps']} steps). "
             "The pooled RMSE is given beside it; it weighs late, large errors more."]
    if "detections" in st:
        d = st["detections"]
        lines.append(f"Detections: every one of the {d['sensors']} transmitter-receiver pairs detects each living target "
                     f"with probability {d['pd']} and reports {d['clutter_per_scan']:g} clutter points per scan "
                     f"({d['clutter_model']}) uniform over {' x '.join(d['components'])}; the single-target methods read "
                     "each target's own clean stream (association known). Random streams: "
                     f"{st.get('random_streams', 'per_block')}; OSPA / GOSPA cut-off {st['set_metrics']['c_m']:g} m, "
                     f"order {st['set_metrics']['p']:g}.")
    return [" ".join(lines), ""]


def write_report(res: dict, out: Path, examples: dict, geometry, ref: dict | None, ref_timing: dict | None,
                 ref_label: str = "paper") -> list[Path]:
    """Write ``out/report.md`` and the figures of any scenario; returns the files written."""
    single_case = bool(ref) and not any(isinstance(v, dict) for v in ref.values())
    cases = res["cases"]
    designed = all(c.get("pcrb") is not None for c in cases.values())
    sweep = res["settings"].get("sweep", "none")
    from .front_end_report import front_end_tables, write_front_end_outputs

    figures = plot_rmse(res, out) + plot_set_metrics(res, out)
    figures.append(plot_trajectories(res, examples, geometry, out / "trajectories.png"))
    figures += write_front_end_outputs(res, examples, out)
    from .plane_report import plane_report

    plane_lines, plane_figures = plane_report(res, examples, out)
    figures += plane_figures
    if sweep != "none":
        figures.append(plot_sweep(res, out / f"sweep_{sweep}.png"))
    env = res["environment"]
    lines = [f"# {res['scenario']}: {res['mc_runs']} Monte Carlo runs per case, seed {res['seed']}", ""]
    if res.get("description"):
        lines += [res["description"].strip(), ""]
    lines += _setting_lines(res)
    lines += ["## Position RMSE (m)" + (", ours beside the paper's" if ref else ""), ""]
    lines += summary_table(res, ref, ref_label, single_case)
    lines.append("")
    lines += space_note(res)
    if ref:
        info = res["reference"]
        lines += [f"Columns marked *{ref_label}* are the paper's numbers, read from `{Path(info['file']).name}` "
                  f"(`{info['table']}`) for reference only; the paper's trajectories are not given numerically, so "
                  "they compare in order of magnitude and ranking, not digit by digit.", ""]
    lines += _flags(res)
    if sweep != "none":
        lines += ["## Sweep", "", *sweep_table(res, ref_timing, ref_label)]
    lines += front_end_tables(res)
    from .rd_maps_report import report_lines as rd_maps_lines

    tbd = rd_maps_lines(res, out, examples)  # rows that read range-Doppler maps: their own section
    figures += [f for f in sorted(out.glob("*.png")) if tbd and f not in figures]
    lines += tbd
    mt = multi_target_tables(res, ref_timing, ref_label)
    if mt:
        lines += ["## Multi-target figures", "", *mt, *per_target_tables(res, ref_label)]
    lines += plane_lines
    lines += learned_tables(res) if designed else []
    lines += tuning_tables(res)
    if designed:
        lines += ["## Per case", ""]
        for name, case in cases.items():
            lines += case_table(name, case, ref, ref_label, single_case) + [""]
            lines += [f"![RMSE vs time]({name}_rmse.png)", ""]
        lines += ["Causal methods are compared with the filtering bound, methods that look ahead with the smoothing "
                  "bound. Diverged runs are counted and kept in the averages.", ""]
    elif sweep == "none":
        lines += ["## RMSE per target vs time", ""] + [f"![{n}]({n}_rmse.png)" for n in cases] + [""]
    lines += ["## Trajectories", "", "![trajectories](trajectories.png)", "",
              "## Run time (measured in this run)", ""]
    lines += timing_table(res, ref_timing, ref_label)
    lines += ["", f"Environment: pmsr_nn {env['pmsr_nn']}, torch {env['torch']}, {env['machine']}, device {env['device']}, "
              f"{env['threads']} threads, {env['date']}, commit {env['commit']}. Command: `{env['command']}`.", "",
              "## Definitions", ""]
    lines += [f"- `{k}`: {v}" for k, v in res["definitions"].items()]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return [out / "report.md", *figures]


def _flags(res: dict) -> list[str]:
    """Honesty flags: methods below their bound (and below the q = 0 floor), diverged runs."""
    st, lines = res["settings"], []
    flagged = [(c, m) for c, v in res["cases"].items() for m, r in v["methods"].items() if r.get("below_bound")]
    if flagged:
        floor = [(c, m) for c, m in flagged if res["cases"][c]["methods"][m]["below_q0_bound"]]
        anees = [res["cases"][c]["methods"][m]["anees"] for c, m in flagged]
        known = [a for a in anees if a is not None]
        def ratio(c, m, key="mse_over_bound"):
            r = res["cases"][c]["methods"][m]
            return f" (MSE / bound^2 {r[key]:.3f} +- {r[key + '_se']:.3f})" if key in r else ""
        lines += ["**Below the bound (bold; beyond the Monte Carlo error: the one-sided 97.5 % Student-t bound "
                  "of the per-run mean squared error over the bound's mean square is under 1):** "
                  + ", ".join(f"{m} on {c}{ratio(c, m)}" for c, m in flagged) + ". "
                  "The per-trajectory PCRB assumes, like the filters, the process noise q of the motion model; "
                  "the designed trajectories have no such process noise, so a filter's error on them "
                  "lacks the part the bound reserves for it"
                  + (f" (the flagged methods' ANEES of {_span(known)} says the same: their errors are "
                     "smaller than their own covariances)" if known else "") +
                  ". The floor for these flights is the bound with q = 0 (last row); "
                  + ("**" + ", ".join(f"{m} on {c}{ratio(c, m, 'mse_over_q0_bound')}" for c, m in floor)
                     + " is below even that floor, beyond its Monte Carlo error: a bug or a mismatch to investigate.**"
                     if floor else "no method is below it beyond its Monte Carlo error."), ""]
    diverged = [f"{m} {r['diverged_runs']}/{r['runs']} on {c}" for c, v in res["cases"].items()
                for m, r in v["methods"].items() if r.get("diverged_runs")]
    if diverged:
        lines += ["**Diverged runs** (position RMSE after the warm-up above "
                  f"{st['divergence_m']:g} m or not finite; kept in every average, see the median per run in "
                  "results.json): " + ", ".join(diverged) + ".", ""]
    return lines


def save_figure(fig, path: Path, dpi: int = 110, rect=None) -> Path:
    """Lay out (within ``rect``, figure fractions, where a legend sits outside), write and close a figure."""
    fig.tight_layout(rect=rect)
    fig.savefig(path, dpi=dpi)
    _plt().close(fig)
    return path


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def method_colours(names) -> dict[str, object]:
    """One colour per method, the same in every figure: matplotlib's ten-colour cycle, or tab20
    for more methods (the cycle would repeat a colour)."""
    names = list(dict.fromkeys(names))
    if len(names) <= 10:
        return {m: f"C{i}" for i, m in enumerate(names)}
    cmap = _plt().get_cmap("tab20")
    return {m: cmap(i % 20) for i, m in enumerate(names)}


def _per_target(curve) -> list:
    """A curve as a list of per-target curves (one target: ``[curve]``)."""
    return curve if curve and isinstance(curve[0], list) else [curve]


def plot_rmse(res: dict, out: Path) -> list[Path]:
    """One figure per case: position RMSE vs time of every method with the PCRB (Fig. 9 analogue);
    with several targets one panel per target (Fig. 3 of the S-MSJPDA paper). A study with a
    sweep has its sweep figure instead."""
    if res["settings"].get("sweep", "none") != "none":
        return []
    plt = _plt()
    paths = []
    dt = res["settings"]["dt_s"]
    warmup = res["settings"].get("warmup_steps", 0)
    for name, case in res["cases"].items():
        cv = case["curves"]
        rmse = {m: _per_target(c) for m, c in cv["rmse_pos_m"].items()}
        T = len(next(iter(rmse.values())))
        cols = min(T, 5)  # more targets wrap onto more rows, so no panel is squashed
        rows = -(-T // cols)
        fig, axes = plt.subplots(rows, cols, figsize=(9.6, 4.8) if T == 1 else (3.6 * cols, 3.2 * rows + 0.6),
                                 sharey=True, squeeze=False)
        for ax in axes.flat[T:]:
            ax.set_visible(False)
        names = case.get("targets", [])
        colours = method_colours(rmse)
        for i, ax in enumerate(axes.flat[:T]):
            t = np.arange(case["steps"]) * dt
            for m, per in rmse.items():
                ax.semilogy(t, per[i], lw=1.2, label=m, color=colours[m])
            if "pcrb_pos_m" in cv:
                ax.semilogy(t, _per_target(cv["pcrb_pos_m"])[i], "k--", lw=1.4, label="PCRB (filtering)")
                ax.semilogy(t, _per_target(cv["pcrb_q0_pos_m"])[i], "--", color="grey", lw=1.0, label="PCRB, q = 0 (floor)")
                if any(not r["causal"] for r in case["methods"].values()):
                    ax.semilogy(t, _per_target(cv["pcrb_smoothing_pos_m"])[i], "k:", lw=1.4, label="PCRB (smoothing)")
            if T == 1:
                ax.axvline(warmup * dt, color="grey", lw=0.8)
            ax.set(xlabel="time (s)", title=f"{case['title']}: {res['mc_runs']} runs" if T == 1 else
                   (names[i] if i < len(names) else f"target {i + 1}"))
            ax.grid(True, which="both", alpha=0.3)
        for row in axes:
            row[0].set_ylabel(_rmse_label(case))
        if T == 1:  # outside the data, right of the panel
            axes[0][0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        else:  # one legend for all panels, below them
            handles, labels = axes[0][0].get_legend_handles_labels()
            fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), fontsize=8, frameon=False)
            fig.suptitle(f"{case['title']}: {res['mc_runs']} runs")
        rect = None if T == 1 else (0, (0.3 + 0.25 * -(-len(labels) // 4)) / fig.get_figheight(), 1, 0.97)
        paths.append(save_figure(fig, out / f"{name}_rmse.png", dpi=110 if T == 1 else 100, rect=rect))
    return paths


def _rmse_label(case: dict) -> str:
    """The y label of a case's RMSE figure: the position, or what every row's "position" is (a
    measurement space's, e.g. bistatic range)."""
    names = {r.get("position") for r in case["methods"].values()}
    return f"{names.pop()} RMSE" if len(names) == 1 and None not in names else "position RMSE (m)"


def plot_set_metrics(res: dict, out: Path) -> list[Path]:
    """Per multi-target case: OSPA, estimated cardinality (with the truth's) and position RMSE
    over targets vs time, every method."""
    plt = _plt()
    paths = []
    dt = res["settings"]["dt_s"]
    for name, case in res["cases"].items():
        cv = case["curves"]
        if "set" not in cv:
            continue
        t = np.arange(case["steps"]) * dt
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.0))
        colours = method_colours(cv["set"])
        for m, c in cv["set"].items():
            label = m + space_mark(case["methods"].get(m, {}))
            axes[0].plot(t, c["ospa_m"], lw=1.1, label=label, color=colours[m])
            axes[1].plot(t, c["cardinality"], lw=1.1, label=label, color=colours[m])
            per = np.asarray(_per_target(cv["rmse_pos_m"][m]), dtype=float)
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # scans without a matched track: NaN, not plotted
                mean_sq = np.nanmean(per**2, axis=0) if np.isfinite(per).any() else per[0]
            axes[2].semilogy(t, np.sqrt(mean_sq), lw=1.1, label=label, color=colours[m])
        axes[1].step(t, cv["cardinality_truth"], "k", where="post", lw=1.6, label="truth")
        for ax, ylabel in zip(axes, (f"OSPA (m, c = {res['settings']['set_metrics']['c_m']:g} m)",
                                     "mean number of tracks", "position RMSE over living targets (m)")):
            ax.set(xlabel="time (s)", ylabel=ylabel)
            ax.grid(True, which="both", alpha=0.3)
        axes[1].yaxis.get_major_locator().set_params(integer=True)  # a count
        handles, labels = axes[1].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=8, frameon=False)
        fig.suptitle(f"{case['title']}: {res['mc_runs']} runs")
        rect = (0, (0.3 + 0.25 * -(-len(labels) // 6)) / fig.get_figheight(), 1, 0.97)
        paths.append(save_figure(fig, out / f"{name}_set_metrics.png", dpi=100, rect=rect))
    return paths


def _path_extent(paths: list[np.ndarray], margin: float = 0.08) -> tuple[np.ndarray, float]:
    """Centre ``(2,)`` and side (same units) of the square holding the finite points of ``paths``
    (each ``(K, ..., 2)``), with ``margin`` of the side added."""
    pts = np.concatenate([p.reshape(-1, 2) for p in paths if p.size]) if paths else np.zeros((1, 2))
    pts = pts[np.isfinite(pts).all(1)]
    if not len(pts):
        return np.zeros(2), 1.0
    lo, hi = pts.min(0), pts.max(0)
    return 0.5 * (lo + hi), max(float((hi - lo).max()), 1e-3) * (1 + 2 * margin)


def plot_trajectories(res: dict, examples: dict, geometry, path: Path) -> Path:
    """Sensors and every case's true paths, then per case run 0's truth and each method's
    estimates (Fig. 8 / 12 analogue).

    The per-case panels share one extent: each is a square window of the same side (the largest
    case's true path, with a margin) centred on its own path, so every panel has the same scale
    and none is squashed; the legends sit below the panels."""
    plt = _plt()
    names = list(res["cases"])
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(3.8 * (len(names) + 1), 4.6), squeeze=False)
    axes = axes[0]
    ax0 = axes[0]
    for i, tx in enumerate(geometry.transmitters):
        ax0.plot(tx.position_m[0] / 1e3, tx.position_m[1] / 1e3, "k^", ms=9, label="transmitter" if i == 0 else None)
    for i, rx in enumerate(geometry.receivers):
        ax0.plot(rx.position_m[0] / 1e3, rx.position_m[1] / 1e3, "bv", ms=7, label="receiver" if i == 0 else None)
    truths = {n: np.asarray(examples.get(n, {}).get("truth", np.zeros((0, 1, 2))), dtype=float) / 1e3 for n in names}
    for j, name in enumerate(names):
        truth = truths[name]
        for t in range(truth.shape[1]):
            ax0.plot(truth[:, t, 0], truth[:, t, 1], color=f"C{j}", lw=1.6, label=name if t == 0 else None)
    ax0.set(xlabel="east (km)", ylabel="north (km)", title="sensors and true trajectories", aspect="equal")
    ax0.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, frameon=False)
    side = max(_path_extent([t])[1] for t in truths.values()) if truths else 1.0
    methods = method_colours(m for n in names for m in examples.get(n, {}) if m != "truth" and not m.startswith("@"))
    for ax, name in zip(axes[1:], names):
        ex = examples.get(name, {})
        truth = truths[name]
        for t in range(truth.shape[1]):
            ax.plot(truth[:, t, 0], truth[:, t, 1], "k", lw=2.2, label="truth" if t == 0 else None)
        for m in (k for k in ex if k != "truth" and not k.startswith("@")):
            colour = methods[m]  # one colour per method in every panel and figure
            est = np.asarray(ex[m], dtype=float) / 1e3
            est = est[:, None] if est.ndim == 2 else est
            for t in range(est.shape[1]):
                ax.plot(est[:, t, 0], est[:, t, 1], color=colour, lw=0.8, label=m if t == 0 else None)
        centre, _ = _path_extent([truth])
        ax.set(xlim=(centre[0] - side / 2, centre[0] + side / 2), ylim=(centre[1] - side / 2, centre[1] + side / 2),
               xlabel="east (km)", ylabel="north (km)", aspect="equal",
               title=textwrap.fill(f"{res['cases'][name]['title']}: run 0", 36))
        ax.grid(True, alpha=0.3)
    entries = {}  # every panel's methods (a case may run fewer), first handle per label
    for ax in axes[1:]:
        for h, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, h)
    if entries:
        fig.legend(list(entries.values()), list(entries), loc="lower center", bbox_to_anchor=(0.6, 0.0),
                   ncol=min(len(entries), 6), fontsize=8, frameon=False)
    return save_figure(fig, path, rect=(0, 0.1, 1, 1))


def plot_sweep(res: dict, path: Path) -> Path:
    """Figs. 4-7 analogue: accuracy, OSPA, loss and swap probabilities and run time against the swept quantity."""
    plt = _plt()
    sweep = res["settings"]["sweep"]
    cases = list(res["cases"].values())
    xs = [c[sweep] for c in cases]
    keys = ("rmse_pos_m", "ospa_m", "loss_probability", "swap_probability", "seconds_per_run")
    fig, axes = plt.subplots(1, len(keys), figsize=(4.2 * len(keys), 3.8))
    for m in cases[0]["methods"]:
        for ax, key in zip(axes, keys):
            ax.plot(xs, [c["methods"][m].get(key, np.nan) for c in cases], "o-", ms=3, label=m)
    for ax, ylabel in zip(axes, ("position RMSE, converged (m)", "OSPA, converged (m)", "loss probability (paper's rule)",
                                 "swap probability (last scan)", "seconds per run (ours)")):
        ax.set(xlabel=SWEEP_LABELS[sweep], ylabel=ylabel)
        ax.grid(True, alpha=0.3)
    axes[-1].legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))  # outside the data
    return save_figure(fig, path, dpi=100)
