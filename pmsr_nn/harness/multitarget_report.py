"""``report.md`` and figures of a multi-target scenario (S-/P-MSJPDA study).

The paper's run times, where the scenario names its table, sit in their own labelled column; the
paper's accuracy is only given as curves (Figs. 3-7), so no accuracy number of the paper appears.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .report import _f, _plt, save_figure

SWEEP_LABELS = {"pd": "detection probability Pd", "clutter_per_scan": "clutter points per sensor per scan",
                "spacing_m": "spacing of the formation (m)"}


def _paper_seconds(timing: dict | None, method: str, key: str | None):
    if not timing or key is None:
        return None
    v = timing.get(method, {}).get(key)
    return v if isinstance(v, (int, float)) else None


def case_tables(res: dict, timing: dict | None, label: str) -> list[str]:
    lines = []
    for name, case in res["cases"].items():
        lines += [f"### {case['title']} (`{name}`: Pd {case['pd']}, {case['clutter_per_scan']:g} clutter per sensor "
                  f"per scan, spacing {case['spacing_m']:g} m)", "",
                  "| method | pos RMSE, converged (m) | pos RMSE, all scans (m) | per target (m) | vel RMSE (m/s) | "
                  f"ANEES | loss prob. | swap prob. | s / run | {label}: s / run |",
                  "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|"]
        for m, r in case["methods"].items():
            per = " / ".join(f"{v:.0f}" for v in r["rmse_pos_per_target_m"])
            lines.append(f"| {m} | {_f(r['rmse_pos_m'], 1)} | {_f(r['rmse_pos_all_scans_m'], 1)} | {per} | "
                         f"{_f(r['rmse_vel_mps'])} | {_f(r['anees'])} | {_f(r['loss_probability'], 3)} | "
                         f"{_f(r['swap_probability'], 3)} | {_f(r['seconds_per_run'], 3)} | "
                         f"{_f(_paper_seconds(timing, m, case['reference_key']))} |")
        lines.append("")
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
    head = "| " + SWEEP_LABELS[sweep] + " | " + " | ".join(f"{m}: RMSE (m) | {m}: loss | {m}: s/run" for m in methods)
    head += "".join(f" | {label}: {m} s/run" for m in timed)
    head += "".join(f" | {m} / {s_ref} time" for m in parallel)
    head += f" | {label}: P/S time |" if paper_ratio else " |"
    lines = [head, "|" + "---:|" * (head.count("|") - 1)]
    for case in res["cases"].values():
        r = case["methods"]
        row = f"| {case[sweep]:g} | " + " | ".join(
            f"{_f(r[m]['rmse_pos_m'], 1)} | {_f(r[m]['loss_probability'], 3)} | {_f(r[m]['seconds_per_run'], 3)}"
            for m in methods)
        row += "".join(f" | {_f(_paper_seconds(timing, m, case['reference_key']))}" for m in timed)
        row += "".join(f" | {r[m]['seconds_per_run'] / r[s_ref]['seconds_per_run']:.1f}" for m in parallel)
        if paper_ratio:
            p, s = (_paper_seconds(timing, m, case["reference_key"]) for m in ("P-MSJPDA", "S-MSJPDA"))
            row += f" | {_f(p / s if p and s else None, 1)}"
        lines.append(row + " |")
    return lines + [""]


def write_multitarget_report(res: dict, out: Path, examples: dict, timing: dict | None, label: str) -> list[Path]:
    st = res["settings"]
    figures = plot_rmse_per_target(res, out)
    figures.append(plot_tracks(res, examples, out / "tracks.png"))
    if st["sweep"] != "none":
        figures.append(plot_sweep(res, out / f"sweep_{st['sweep']}.png"))
    tx = ", ".join(f"({p['position_m'][0] / 1e3:g}, {p['position_m'][1] / 1e3:g}) km at {p['carrier_hz'] / 1e6:g} MHz"
                   for p in st["transmitters"])
    lines = [f"# {res['scenario']}", "", res.get("description", "").strip(), "",
             f"{res['mc_runs']} Monte Carlo runs per case (seed {res['seed']}), {st['scans']} scans of {st['dt_s']} s. "
             f"Transmitters {tx}; receiver at {st['receivers'][0]}. Noise: range {st['noise']['range_m']} m, Doppler "
             f"{st['noise']['doppler_hz']} Hz. Clutter: {st['clutter']['model']}, uniform over range "
             f"{st['clutter']['range_m']} m x Doppler {st['clutter']['doppler_hz']} Hz. Trackers: UKF moments, "
             f"m = {st['tracker']['m_best']} best events, gate probability {st['tracker']['gate_probability']}, "
             f"CV with q = {st['q']} m^2/s^4 (the truth's). Loss rule: {st['loss']['successive_scans']} scans "
             f"dummy-most-probable, or predicted range deviation > {st['loss']['gate_range_sd_m']:g} m.", ""]
    if st["sweep"] != "none":
        lines += ["## Sweep", "", *sweep_table(res, timing, label)]
    lines += ["## Cases", "", *case_tables(res, timing, label), "## Figures", ""]
    lines += [f"![{p.stem}]({p.name})" for p in figures]
    lines += ["", "## Definitions", ""] + [f"- `{k}`: {v}" for k, v in res["definitions"].items()]
    env = res["environment"]
    lines += ["", f"Machine: {env.get('cpu', '?')}, torch {env.get('torch', '?')}, {env.get('threads', '?')} threads, "
                  f"pmsr_nn {env.get('pmsr_nn', '?')} (commit {env.get('git_commit', '?')})."]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return [out / "report.md", *figures]


def plot_rmse_per_target(res: dict, out: Path) -> list[Path]:
    """Fig. 3 analogue: per target, position RMSE vs time of every method (cases without a sweep)."""
    if res["settings"]["sweep"] != "none":
        return []
    plt = _plt()
    paths = []
    dt = res["settings"]["dt_s"]
    for name, case in res["cases"].items():
        curves = case["curves"]["rmse_pos_m_per_target"]
        T = len(next(iter(curves.values())))
        fig, axes = plt.subplots(1, T, figsize=(3.6 * T, 3.6), sharey=True, squeeze=False)
        for t, ax in enumerate(axes[0]):
            for m, per in curves.items():
                ax.semilogy(np.arange(len(per[t])) * dt, per[t], lw=1.2, label=m)
            ax.set(xlabel="time (s)", title=f"target {t + 1}")
            ax.grid(True, which="both", alpha=0.3)
        axes[0][0].set_ylabel("position RMSE (m)")
        axes[0][0].legend(fontsize=7)
        fig.suptitle(f"{case['title']}: {res['mc_runs']} runs")
        paths.append(save_figure(fig, out / f"{name}_rmse_per_target.png", dpi=100))
    return paths


def plot_tracks(res: dict, examples: dict, path: Path) -> Path:
    """Sensors, and for every case run 0's true paths (black) and each method's tracks."""
    plt = _plt()
    names = list(examples)
    fig, axes = plt.subplots(1, len(names), figsize=(4.6 * len(names), 4.4), squeeze=False)
    for ax, name in zip(axes[0], names):
        ex = examples[name]
        truth = ex["truth"]  # (K, T, 2)
        for t in range(truth.shape[1]):
            ax.plot(truth[:, t, 0] / 1e3, truth[:, t, 1] / 1e3, "k", lw=2.0, label="truth" if t == 0 else None)
        for j, m in enumerate(k for k in ex if k != "truth"):
            for t in range(ex[m].shape[1]):
                ax.plot(ex[m][:, t, 0] / 1e3, ex[m][:, t, 1] / 1e3, color=f"C{j}", lw=0.9, label=m if t == 0 else None)
        ax.set(xlabel="east (km)", ylabel="north (km)", title=f"{res['cases'][name]['title']}: run 0", aspect="equal")
        ax.legend(fontsize=6)
    return save_figure(fig, path, dpi=100)


def plot_sweep(res: dict, path: Path) -> Path:
    """Figs. 4-7 analogue: accuracy, loss and swap probabilities and run time against the swept quantity."""
    plt = _plt()
    sweep = res["settings"]["sweep"]
    cases = list(res["cases"].values())
    xs = [c[sweep] for c in cases]
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.8))
    keys = ("rmse_pos_m", "loss_probability", "swap_probability", "seconds_per_run")
    for m in cases[0]["methods"]:
        for ax, key in zip(axes, keys):
            ax.plot(xs, [c["methods"][m][key] for c in cases], "o-", ms=3, label=m)
    for ax, ylabel in zip(axes, ("position RMSE, converged (m)", "loss probability (paper's rule)",
                                 "swap probability (last scan)", "seconds per run (ours)")):
        ax.set(xlabel=SWEEP_LABELS[sweep], ylabel=ylabel)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7)
    return save_figure(fig, path, dpi=100)
