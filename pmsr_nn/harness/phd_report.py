"""``report.md`` and figures of an SMC-PHD study (:mod:`.phd_study`).

Per case, in the seed's Fig. 4 style (run 0; the seed's radial velocity is our range-rate with
the opposite sign: approaching aircraft have a negative range-rate here):

* ``<case>_phd_rr.png``: range-rate vs bistatic range, the flights (black, start ``o``, end
  ``^``) and the SMC-PHD estimates (dots), Fig. 4a; ``<case>_phd_time.png``: range and range-rate
  vs time, Fig. 4b;
* ``<case>_<method>_rr.png`` / ``<case>_<method>_time.png``: the labelled estimates coloured by
  label, Figs. 4c / 4d;
* ``<case>_cardinality.png``: true cardinality, the PHD's integral, its estimates and each
  method's tracks vs time (mean over runs); ``<case>_ospa.png``: OSPA vs time.

Across cases: ``sweep_clutter.png`` and ``sweep_pd.png`` (OSPA, label switches and
fragmentations of each labelling vs the clutter rate at the study's Pd, and vs Pd at its
clutter rate), where the cases span at least two values.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .phd_study import PHD
from .tbd_report import _fmt, _plt


def _legend_outside(ax) -> None:
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)


def _truth(ax_rr, axes_t, setup) -> None:
    """The flights in black on the range-rate vs range axes and on the range / range-rate vs time axes."""
    z, alive, dt = setup.z.numpy(), setup.alive.numpy(), setup.scenario.dt_s
    t = np.arange(z.shape[0]) * dt
    for i in range(z.shape[1]):
        on = alive[:, i]
        r, v = np.where(on, z[:, i, 0] / 1e3, np.nan), np.where(on, z[:, i, 1], np.nan)
        label = "flights" if i == 0 else None
        if ax_rr is not None:
            ax_rr.plot(r, v, color="k", lw=1.2, label=label)
            first, last = np.flatnonzero(on)[[0, -1]]
            ax_rr.plot(r[first], v[first], "o", mfc="none", color="k", ms=6)
            ax_rr.plot(r[last], v[last], "^", mfc="none", color="k", ms=6)
        if axes_t is not None:
            axes_t[0].plot(t, r, color="k", lw=1.2, label=label)
            axes_t[1].plot(t, v, color="k", lw=1.2)


def _points(x: np.ndarray, exists: np.ndarray, dt: float, labelled: bool):
    """Per label (or one group for unlabelled estimates): time, range (km), range-rate of each estimate."""
    K, M = exists.shape
    t = np.arange(K)[:, None].repeat(M, 1) * dt
    groups = range(M) if labelled else [None]
    for m in groups:
        on = exists[:, m] if m is not None else exists
        if not on.any():
            continue
        xs = x[:, m] if m is not None else x
        yield m, t[:, m][on] if m is not None else t[on], xs[on][..., 0] / 1e3, xs[on][..., 1]


def _example_figures(out: Path, cname: str, case: dict, setup, ex: dict) -> list[str]:
    plt = _plt()
    dt = setup.scenario.dt_s
    K = setup.z.shape[0]
    sets = {PHD: (ex["phd"], False)} | {n: (v, True) for n, v in ex["tracks"].items()}
    names = []
    for name, ((x, exists), labelled) in sets.items():
        title = "SMC-PHD estimates" if name == PHD else f"{case['methods'][name]['kind']} ({name})"
        cmap = plt.get_cmap("tab20")
        fig, ax = plt.subplots(figsize=(7.5, 5.2))
        _truth(ax, None, setup)
        for m, t, r, v in _points(x, exists, dt, labelled):
            ax.plot(r, v, ".", ms=3, color=cmap(m % 20) if labelled else "tab:blue",
                    label=None if labelled else "estimates")
        ax.set_xlabel("bistatic range (km)")
        ax.set_ylabel("bistatic range-rate (m/s)")
        ax.set_title(f"{case['title']}: {title}, run 0" + (" (colour: label)" if labelled else ""), fontsize=10)
        if not labelled:
            _legend_outside(ax)
        fig.tight_layout()
        fig.savefig(out / f"{cname}_{name}_rr.png", dpi=110)
        plt.close(fig)
        fig, axes = plt.subplots(2, 1, figsize=(9, 6.4), sharex=True)
        _truth(None, axes, setup)
        for m, t, r, v in _points(x, exists, dt, labelled):
            color = cmap(m % 20) if labelled else "tab:blue"
            axes[0].plot(t, r, ".", ms=2.5, color=color)
            axes[1].plot(t, v, ".", ms=2.5, color=color)
        axes[0].set_ylabel("bistatic range (km)")
        axes[1].set_ylabel("bistatic range-rate (m/s)")
        axes[1].set_xlabel("time (s)")
        axes[0].set_xlim(0, K * dt)
        axes[0].set_title(f"{case['title']}: {title} vs time, run 0" + (" (colour: label)" if labelled else ""),
                          fontsize=10)
        fig.tight_layout()
        fig.savefig(out / f"{cname}_{name}_time.png", dpi=110)
        plt.close(fig)
        names += [f"{cname}_{name}_rr.png", f"{cname}_{name}_time.png"]
    return names


def _time_figure(path: Path, t: np.ndarray, series: dict, ylabel: str, title: str, thick: str | None = None) -> None:
    plt = _plt()
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


def _time_figures(out: Path, cname: str, case: dict, dt: float) -> list[str]:
    m = case["methods"]
    t = np.arange(len(case["true_cardinality"])) * dt
    label = lambda n: "PHD estimates" if n == PHD else f"{n} tracks"
    _time_figure(out / f"{cname}_cardinality.png", t,
                 {"true": case["true_cardinality"], "PHD integral (sum of weights)": m[PHD]["expected"],
                  **{label(n): r["cardinality"] for n, r in m.items()}},
                 "number of targets (mean over runs)", f"{case['title']}: cardinality", thick="true")
    _time_figure(out / f"{cname}_ospa.png", t, {label(n): r["ospa_m"] for n, r in m.items()},
                 "OSPA on bistatic range (m)", f"{case['title']}: OSPA, mean over runs")
    return [f"{cname}_cardinality.png", f"{cname}_ospa.png"]


def _sweeps(res: dict, out: Path) -> list[str]:
    """OSPA, switches and fragmentations vs clutter (at the study's Pd) and vs Pd (at its clutter)."""
    plt = _plt()
    base_pd, base_clutter = res["settings"]["pd"], res["settings"]["clutter"]["per_scan"]
    lines = []
    for key, fixed_key, fixed, xlabel, fname in (("clutter_per_scan", "pd", base_pd, "clutter points per scan", "sweep_clutter"),
                                                 ("pd", "clutter_per_scan", base_clutter, "Pd", "sweep_pd")):
        cases = sorted((c for c in res["cases"].values() if c[fixed_key] == fixed), key=lambda c: c[key])
        if len({c[key] for c in cases}) < 2:
            continue
        xs = [c[key] for c in cases]
        methods = [n for n, r in cases[0]["methods"].items() if "label_switches_per_run" in r]
        every = [n for n in cases[0]["methods"] if all(n in c["methods"] for c in cases)]
        colour = {n: plt.get_cmap("tab10")(i % 10) for i, n in enumerate(every)}  # one colour per method, every panel
        style = {n: "--" if n in methods[1:] else "-" for n in every}  # labellings that coincide stay visible
        fig, axes = plt.subplots(1, 3, figsize=(14, 4.0))
        for n in every:
            axes[0].plot(xs, [c["methods"][n]["ospa_mean_m"] for c in cases], marker="o", color=colour[n],
                         ls=style[n], label="PHD estimates" if n == PHD else n)
        for n in methods:
            axes[1].plot(xs, [c["methods"][n]["label_switches_per_run"] for c in cases], marker="o", color=colour[n],
                         ls=style[n])
            axes[2].plot(xs, [c["methods"][n]["fragmentations_per_run"] for c in cases], marker="o", color=colour[n],
                         ls=style[n])
        for ax, ylabel in zip(axes, ("OSPA (m), mean over scans", "label switches per run", "fragmentations per run")):
            ax.set_xlabel(xlabel)
            ax.set_ylabel(ylabel)
        axes[2].legend(*axes[0].get_legend_handles_labels(), loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        fig.suptitle(f"vs {xlabel} ({fixed_key} {fixed:g})", fontsize=10)
        fig.tight_layout()
        fig.savefig(out / f"{fname}.png", dpi=110)
        plt.close(fig)
        lines.append(f"![{fname}]({fname}.png)")
    return lines


def _reference_lines(ref: dict | None, res: dict) -> list[str]:
    if not ref:
        return []
    t = ref["table"]
    s = res["settings"]
    rows = [("carrier (MHz)", t.get("carrier_mhz"), s["geometry"]["transmitters"][0]["carrier_hz"] / 1e6),
            ("duration (s)", t.get("duration_s"), s["scans"] * s["dt_s"]),
            ("aircraft", t.get("aircraft"), len(s["aircraft"])),
            ("max range (km)", t.get("max_range_km"), s["max_range_m"] / 1e3),
            ("range / range-rate deviation", f"{t.get('sigma_r_m')} m / {t.get('sigma_v_mps')} m/s",
             f"{s['noise']['range_m']:g} m / {s['noise']['range_rate_mps']:g} m/s"),
            ("process sigma (m/s^2)", 1e3 * t.get("process_sigma_km_s2", float("nan")), s["phd"]["process_sd_mps2"]),
            ("particles per target / per birth", f"{t.get('particles_per_target')} / {t.get('birth_particles_per_target')}",
             f"{s['phd']['particles_per_target']} / {s['phd']['particles_per_birth']}")]
    lines = [f"Set-up beside the seed's ({ref['label']}: {ref['key']}; the seed reports figures only, no numbers "
             "to compare; its data are a field recording, ours a simulation of its stated set-up):", "",
             f"| quantity | {ref['label']} | this study |", "|---|---|---|"]
    lines += [f"| {q} | {a} | {b} |" for q, a, b in rows]
    return lines + [""]


def write_phd_report(res: dict, setup, examples: dict, out: Path) -> None:
    dt = res["settings"]["dt_s"]
    lines = [f"# {res['scenario']}", "", res.get("description", "").strip(), "",
             f"{res['mc_runs']} Monte Carlo runs, seed {res['seed']}, {res['settings']['scans']} scans of {dt:g} s. "
             "OSPA / GOSPA on bistatic range (cut-off "
             f"{res['settings']['set_metrics']['c_m']:g} m, order {res['settings']['set_metrics']['p']:g}). "
             "Definitions in results.json.", ""]
    lines += _reference_lines(res.get("reference"), res)
    names = res["settings"]["aircraft"]
    for cname, case in res["cases"].items():
        m = case["methods"]
        source = {"simulated": "simulated detections", "signals": "detections from the FM front end's signal chain"}.get(
            case["detections"], f"detections read from {case['detections']}")
        lines += [f"## {case['title']}", "", f"Pd {case['pd']:g}, {case['clutter_per_scan']:g} clutter points per scan; "
                  f"{source}; the filter's deviations {case['noise']['range_m']:g} m and "
                  f"{case['noise']['range_rate_mps']:g} m/s.", ""]
        fe = case.get("front_end")
        if fe:
            lines += [f"Front end, measured: Pd {fe['pd_measured']:.3f} while in the map, {fe['false_alarms_per_map']:.2f} false "
                      f"alarms per map (nominal {fe['nominal_false_alarms_per_map']:.2f}), range RMSE "
                      f"{_fmt(fe['rmse_range_m'])} m, Doppler RMSE {_fmt(fe['rmse_doppler_hz'], 3)} Hz, "
                      f"{fe['processing_seconds_per_cpi'] * 1e3:.0f} ms per CPI.", ""]
        lines += ["| method | OSPA m | GOSPA m | abs. card. error | RMS range m | RMS range-rate m/s | label switches / run | "
                  "fragmentations / run | labels / run | s / run |", "|---|---|---|---|---|---|---|---|---|---|"]
        for n, r in m.items():
            lines.append(f"| {r['kind']} | {r['ospa_mean_m']:.0f} | "
                         f"{r['gospa_mean_m']:.0f} | {r['mean_abs_cardinality_error']:.2f} | {_fmt(r['rms_range_m'])} | "
                         f"{_fmt(r['rms_range_rate_mps'], 2)} | {_fmt(r.get('label_switches_per_run'), 2)} | "
                         f"{_fmt(r.get('fragmentations_per_run'), 2)} | {_fmt(r.get('labels_per_run'), 1)} | "
                         f"{r['seconds_per_run']:.2f} |")
        labelled = [n for n, r in m.items() if "label_switches_per_target" in r]
        lines += ["", "Per aircraft, mean over runs: label switches / fragmentations", "",
                  "| aircraft | " + " | ".join(labelled) + " |", "|---|" + "---|" * len(labelled)]
        for i, a in enumerate(names):
            lines.append(f"| {a} | " + " | ".join(f"{m[n]['label_switches_per_target'][i]:.2f} / "
                                                  f"{m[n]['fragmentations_per_target'][i]:.2f}" for n in labelled) + " |")
        lines.append("")
        figs = _time_figures(out, cname, case, dt)
        if cname in examples:
            figs = _example_figures(out, cname, case, setup, examples[cname]) + figs
        lines += [f"![{f[:-4]}]({f})" for f in figs] + [""]
    lines += _sweeps(res, out)
    (out / "report.md").write_text("\n".join(lines) + "\n")
