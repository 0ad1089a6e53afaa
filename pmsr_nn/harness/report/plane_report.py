"""The report's part for rows scored in one pair's bistatic plane (:mod:`pmsr_nn.methods.phd_pair`).

Written only where some row has a space (``space`` in its results): per case a table of the set
figures in that plane (OSPA / GOSPA on bistatic range, cardinality, range and range-rate RMSE over
matched pairs, label switches, fragmentations and labels per run, seconds with the PHD's part),
label switches and fragmentations per target, and in the Daniyan seed's Fig. 4 style (run 0; the
seed's radial velocity is our range-rate with the opposite sign: approaching aircraft have a
negative range-rate here):

* ``<case>_<method>_rr.png``: range-rate vs bistatic range, the flights (black, start ``o``, end
  ``^``) and the row's estimates (coloured by label where labelled), Figs. 4a / 4c;
  ``<case>_<method>_time.png``: range and range-rate vs time, Figs. 4b / 4d;
* ``<case>_cardinality.png``: true cardinality, the PHD's integral and every row's estimates or
  tracks vs time (mean over runs); ``<case>_ospa.png``: OSPA vs time.

Across cases: ``sweep_clutter.png`` and ``sweep_pd.png`` (OSPA, label switches and fragmentations
of the plane's rows vs the clutter rate at the scenario's Pd, and vs Pd at its clutter rate),
where the cases span at least two values. And the paper's stated set-up beside the scenario's,
where the scenario names one (``reference.setup``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..results.result_rows import MethodRow
from ..results.typed import Case, Results
from .figures import pyplot
from .report_cells import fmt, fmt_se, switch_column


def _plane_rows(case: Case) -> dict[str, MethodRow]:
    return {m: r for m, r in case.methods.items() if r.space is not None}


def _legend_outside(ax) -> None:
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)


def _truth(ax_rr, axes_t, z: np.ndarray, dt: float) -> None:
    """The flights ``z (K, N, 2)`` (NaN where not alive) in black on the range-rate vs range axes and
    on the range / range-rate vs time axes."""
    t = np.arange(z.shape[0]) * dt
    for i in range(z.shape[1]):
        on = np.isfinite(z[:, i, 0])
        if not on.any():
            continue
        r, v = z[:, i, 0] / 1e3, z[:, i, 1]
        label = "flights" if i == 0 else None
        if ax_rr is not None:
            ax_rr.plot(r, v, color="k", lw=1.2, label=label)
            first, last = np.flatnonzero(on)[[0, -1]]
            ax_rr.plot(r[first], v[first], "o", mfc="none", color="k", ms=6)
            ax_rr.plot(r[last], v[last], "^", mfc="none", color="k", ms=6)
        if axes_t is not None:
            axes_t[0].plot(t, r, color="k", lw=1.2, label=label)
            axes_t[1].plot(t, v, color="k", lw=1.2)


def _points(x: np.ndarray, dt: float, labelled: bool):
    """Per label (or one group for unlabelled estimates): time, range (km), range-rate of each
    estimate of ``x (K, M, 2)`` (NaN where none)."""
    K, M = x.shape[:2]
    exists = np.isfinite(x[..., 0])
    t = np.arange(K)[:, None].repeat(M, 1) * dt
    for m in (range(M) if labelled else [None]):
        on = exists[:, m] if m is not None else exists
        if not on.any():
            continue
        xs, ts = (x[:, m], t[:, m]) if m is not None else (x, t)
        yield m, ts[on], xs[on][..., 0] / 1e3, xs[on][..., 1]


def _example_figures(out: Path, cname: str, case: Case, ex: dict, dt: float) -> list[str]:
    plt = pyplot()
    names = []
    cmap = plt.get_cmap("tab20")
    for name, r in _plane_rows(case).items():
        if f"@{name}" not in ex or f"@truth {r.space.key}" not in ex:
            continue
        x, z = np.asarray(ex[f"@{name}"], dtype=float), np.asarray(ex[f"@truth {r.space.key}"], dtype=float)
        labelled = r.labelled
        title = f"{name} ({r.kind})"
        fig, ax = plt.subplots(figsize=(7.5, 5.2))
        _truth(ax, None, z, dt)
        for m, t, rr, v in _points(x, dt, labelled):
            ax.plot(rr, v, ".", ms=3, color=cmap(m % 20) if labelled else "tab:blue",
                    label=None if labelled else "estimates")
        ax.set_xlabel("bistatic range (km)")
        ax.set_ylabel("bistatic range-rate (m/s)")
        ax.set_title(f"{case.title}: {title}, run 0" + (" (colour: label)" if labelled else ""), fontsize=10)
        if not labelled:
            _legend_outside(ax)
        fig.tight_layout()
        fig.savefig(out / f"{cname}_{name}_rr.png", dpi=110)
        plt.close(fig)
        fig, axes = plt.subplots(2, 1, figsize=(9, 6.4), sharex=True)
        _truth(None, axes, z, dt)
        for m, t, rr, v in _points(x, dt, labelled):
            color = cmap(m % 20) if labelled else "tab:blue"
            axes[0].plot(t, rr, ".", ms=2.5, color=color)
            axes[1].plot(t, v, ".", ms=2.5, color=color)
        axes[0].set_ylabel("bistatic range (km)")
        axes[1].set_ylabel("bistatic range-rate (m/s)")
        axes[1].set_xlabel("time (s)")
        axes[0].set_xlim(0, z.shape[0] * dt)
        axes[0].set_title(f"{case.title}: {title} vs time, run 0" + (" (colour: label)" if labelled else ""),
                          fontsize=10)
        fig.tight_layout()
        fig.savefig(out / f"{cname}_{name}_time.png", dpi=110)
        plt.close(fig)
        names += [f"{cname}_{name}_rr.png", f"{cname}_{name}_time.png"]
    return names


def _time_figure(path: Path, t: np.ndarray, series: dict, ylabel: str, title: str, thick: str | None = None) -> None:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.2))
    for name, y in series.items():
        ax.plot(t, y, color="k" if name == thick else None, lw=2 if name == thick else 1, label=name)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    _legend_outside(ax)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _label(name: str, row: MethodRow) -> str:
    return f"{name} tracks" if row.labelled else f"{name} estimates"


def _time_figures(out: Path, cname: str, case: Case, dt: float) -> list[str]:
    rows = _plane_rows(case)
    sets = case.curves.set
    t = np.arange(case.steps) * dt
    series = {"true": case.curves.cardinality_truth}
    integrals = {}  # one curve per distinct PHD run (rows that share one have the same integral)
    for n in rows:
        if sets[n].phd_expected is not None and not any(sets[n].phd_expected == v for v in integrals.values()):
            integrals[n] = sets[n].phd_expected
    for n, v in integrals.items():
        series["PHD integral (sum of weights)" if len(integrals) == 1 else f"{n}: PHD integral"] = v
    series.update({_label(n, r): sets[n].cardinality for n, r in rows.items()})
    _time_figure(out / f"{cname}_cardinality.png", t, series, "number of targets (mean over runs)",
                 f"{case.title}: cardinality", thick="true")
    _time_figure(out / f"{cname}_ospa.png", t, {_label(n, r): sets[n].ospa_m for n, r in rows.items()},
                 "OSPA on bistatic range (m)", f"{case.title}: OSPA, mean over runs")
    return [f"{cname}_cardinality.png", f"{cname}_ospa.png"]


def _sweeps(results: Results, out: Path) -> list[str]:
    """OSPA, switches and fragmentations vs clutter (at the scenario's Pd) and vs Pd (at its clutter)."""
    plt = pyplot()
    st = results.settings.sections
    if "pd" not in st:
        return []
    base_pd, base_clutter = st["pd"], st["clutter"]["per_scan"]
    lines = []
    for key, fixed_key, fixed, xlabel, fname in (("clutter_per_scan", "pd", base_pd, "clutter points per scan",
                                                  "sweep_clutter"),
                                                 ("pd", "clutter_per_scan", base_clutter, "Pd", "sweep_pd")):
        cases = sorted((c for c in results.cases.values() if c.study and getattr(c.study, fixed_key) == fixed),
                       key=lambda c: getattr(c.study, key))
        if len({getattr(c.study, key) for c in cases}) < 2:
            continue
        xs = [getattr(c.study, key) for c in cases]
        every = [n for n in _plane_rows(cases[0]) if all(n in _plane_rows(c) for c in cases)]
        switch_head, switches = switch_column({n: cases[0].methods[n] for n in every})
        labelled = [n for n in every if switches(cases[0].methods[n].sets) is not None]
        colour = {n: plt.get_cmap("tab10")(i % 10) for i, n in enumerate(every)}  # one colour per row, every panel
        style = {n: "--" if n in labelled[1:] else "-" for n in every}  # labellings that coincide stay visible
        fig, axes = plt.subplots(1, 3, figsize=(14, 4.0))
        for n in every:
            axes[0].plot(xs, [c.methods[n].sets.ospa_m for c in cases], marker="o", color=colour[n], ls=style[n],
                         label=n)
        for n in labelled:
            axes[1].plot(xs, [switches(c.methods[n].sets) for c in cases], marker="o", color=colour[n],
                         ls=style[n])
            axes[2].plot(xs, [c.methods[n].tracks.fragmentations_per_run for c in cases], marker="o", color=colour[n],
                         ls=style[n])
        for ax, ylabel in zip(axes, ("OSPA on bistatic range (m), mean over scans", switch_head.replace(" / ", " per "),
                                     "fragmentations per run")):
            ax.set_xlabel(xlabel)
            ax.set_ylabel(ylabel)
        axes[2].legend(*axes[0].get_legend_handles_labels(), loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        fig.suptitle(f"vs {xlabel} ({fixed_key} {fixed:g})", fontsize=10)
        fig.tight_layout()
        fig.savefig(out / f"{fname}.png", dpi=110)
        plt.close(fig)
        lines.append(f"![{fname}]({fname}.png)")
    return lines


def _setup_lines(results: Results) -> list[str]:
    """The paper's stated set-up beside the scenario's (``reference.setup``)."""
    ref = results.reference.get("setup")
    if not ref:
        return []
    from ...methods import method_kind

    t, s, label = ref["table"], results.settings.sections, results.reference.get("label", "paper")
    phd = next((m.options for m in results.settings.methods.values() if m.kind == "smc_phd_pair"), None)
    opt = (lambda k: phd.get(k, method_kind("smc_phd_pair").options[k].default)) if phd else (lambda k: None)
    noise = s["noise"]
    rows = [("carrier (MHz)", t.get("carrier_mhz"), s["transmitters"][0]["carrier_hz"] / 1e6),
            ("duration (s)", t.get("duration_s"), s["scans"] * s["dt_s"]),
            ("aircraft", t.get("aircraft"), len(s.get("aircraft", []))),
            ("max range (km)", t.get("max_range_km"), None if s.get("max_range_m") is None else s["max_range_m"] / 1e3),
            ("range / range-rate deviation", f"{t.get('sigma_r_m')} m / {t.get('sigma_v_mps')} m/s",
             f"{noise['range_m']:g} m / {noise.get('range_rate_mps', '-')} m/s"),
            ("process sigma (m/s^2)", 1e3 * t.get("process_sigma_km_s2", float("nan")), opt("process_sd_mps2")),
            ("particles per target / per birth", f"{t.get('particles_per_target')} / {t.get('birth_particles_per_target')}",
             f"{opt('particles_per_target')} / {opt('particles_per_birth')}" + (
                 f" per scan's births, at least {opt('birth_particles_min')} per detection no target explains (adaptive)"
                 if phd and opt("births") == "adaptive" else ""))]
    lines = [f"Set-up beside the seed's ({label}: {ref['key']}; the seed reports figures only, no numbers to compare; "
             "its data are a field recording, ours a simulation of its stated set-up):", "",
             f"| quantity | {label} | this scenario |", "|---|---|---|"]
    return lines + [f"| {q} | {a} | {b} |" for q, a, b in rows] + [""]


def plane_report(res: Results | dict, examples: dict, out: Path) -> tuple[list[str], list[Path]]:
    """The report's lines and figures for rows scored in a bistatic plane (empty when there are none)."""
    results = Results.of(res)
    if not any(_plane_rows(c) for c in results.cases.values()):
        return [], []
    st = results.settings
    dt = st.dt_s
    lines = ["## Rows scored in a bistatic plane", "",
             "These rows' estimates are one transmitter-receiver pair's bistatic range and range-rate [r, rdot], scored "
             "against the truth projected into that pair's measurement space (each living target's noise-free range "
             "and range-rate). OSPA / GOSPA (cut-off "
             f"{st.set_metrics.c_m:g} m, order {st.set_metrics.p:g}) are on the "
             "bistatic range alone (one axis, in metres); range and range-rate errors are over the estimate-target "
             "pairs the OSPA assignment matches. **Not comparable with a Cartesian row's OSPA or position RMSE.** "
             "A known-association reference's switches, where records counted them on each scan's OSPA assignment, "
             "are that one-axis assignment trading two targets whose ranges cross (its tracks never change target): "
             "they measure the range-only scoring, not the filter. Seconds per run count the PHD filter's in full in every row that reads it (it runs once per "
             "block and settings; its own share in brackets), plus the row's labelling.", ""]
    lines += _setup_lines(results)
    figures = []
    for cname, case in results.cases.items():
        rows = _plane_rows(case)
        if not rows:
            continue
        source = "detections from the FM front end's signal chain" if case.study.detections_from == "signals" \
            else "simulated detections"
        space = next(iter(rows.values())).space.title
        switch_head, switches = switch_column(rows)
        ident = switch_head.startswith("ID")
        lines += [f"### {case.title} (`{cname}`, {space})", "",
                  f"Pd {case.study.pd:g}, {case.study.clutter_per_scan:g} clutter points per scan; {source}.", "",
                  "| method | kind | tracks start | OSPA m | GOSPA m | abs. card. error | RMS range m | RMS range-rate m/s | "
                  f"{switch_head} | fragmentations / run | labels / run | s / run (PHD) |",
                  "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for n, r in rows.items():
            kind = r.kind + ("" if r.labelled else ", unlabelled")
            phd = f" ({r.phd_seconds_per_run:.2f})" if r.phd_seconds_per_run is not None else ""
            s, tracks = r.sets, r.tracks
            lines.append(f"| {n} | {kind} | {r.initiation} | {fmt_se(s.ospa_m, s.ospa_se_m, 1)} | "
                         f"{fmt_se(s.gospa_m, s.gospa_se_m, 1)} | "
                         f"{fmt(s.cardinality_mean_abs_error, 3)} | {fmt(r.rmse_pos_pooled_m, 1)} | "
                         f"{fmt(r.space.rmse_vel_pooled_mps, 2)} | {fmt(switches(s), 2)} | "
                         f"{fmt(tracks.fragmentations_per_run if tracks else None, 2)} | {fmt(r.labels_per_run, 1)} | "
                         f"{r.seconds_per_run:.2f}{phd} |")
        per = (lambda r: r.sets.id_switches_per_target) if ident else (lambda r: r.sets.label_switches_per_target)
        labelled = [n for n, r in rows.items() if per(r) is not None]
        if labelled:
            lines += ["", f"Per target, mean over runs: {'identity' if ident else 'label'} switches / fragmentations", "",
                      "| target | " + " | ".join(labelled) + " |", "|---|" + "---|" * len(labelled)]
            for i, a in enumerate(case.targets):
                lines.append(f"| {a} | " + " | ".join(f"{per(rows[n])[i]:.2f} / "
                                                      f"{rows[n].tracks.fragmentations_per_target[i]:.2f}"
                                                      for n in labelled) + " |")
        lines.append("")
        figs = _example_figures(out, cname, case, examples.get(cname, {}), dt) + _time_figures(out, cname, case, dt)
        figures += [out / f for f in figs]
        lines += [f"![{f[:-4]}]({f})" for f in figs] + [""]
    sweeps = _sweeps(results, out)
    figures += [out / (s.split("(")[1][:-1]) for s in sweeps]
    return lines + sweeps + ([""] if sweeps else []), figures
