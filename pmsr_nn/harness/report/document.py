"""``report.md`` and PNG figures of a scenario's results (and the example run's estimates):
:func:`write_report` assembles the sections the table, flag and figure modules write.

It reads the typed results (:class:`pmsr_nn.harness.results.typed.Results`), built once from the ``results.json`` dict.
The paper's numbers, where the scenario names a reference table, are printed in their own column
labelled as the paper's; they are read from the reference file and never enter a figure of ours.
"""

from __future__ import annotations

from pathlib import Path

from ..results.typed import Results
from .bound_tables import case_table, learned_tables
from .figures import plot_rmse, plot_set_metrics, plot_sweep
from .flags import flag_paragraphs
from .front_end_report import front_end_tables, write_front_end_outputs
from .method_tables import summary_table, timing_table, tuning_tables
from .multitarget_tables import multi_target_tables, per_target_tables, space_note, sweep_table
from .plane_report import plane_report
from .rd_maps_report import report_lines as rd_maps_lines
from .track_figure import drawn_cases, plot_case_tracks
from .trajectory_figure import plot_trajectories


def _world_lines(results: Results) -> list[str]:
    """The sentences of a scenario with its own world (``settings`` has ``scans``; also a
    ``kind: multitarget`` study's results.json, written before that schema was retired)."""
    st = results.settings.sections
    tx = ", ".join(f"({p['position_m'][0] / 1e3:g}, {p['position_m'][1] / 1e3:g}) km at {p['carrier_hz'] / 1e6:g} MHz"
                   for p in st["transmitters"])
    tr = results.settings.methods
    m_best = sorted({v.options["m_best"] for v in tr.values() if "m_best" in v.options})
    gates = sorted({v.options["gate_probability"] for v in tr.values() if "gate_probability" in v.options})
    gate = st["tracker"]["gate_probability"] if "tracker" in st else ", ".join(map(str, gates)) or "-"
    mo = st.get("motion", {"model": "cv", "vertical_q": None, "truth": "sampled"})
    unit = "m^2/s^3 (PSD of continuous white acceleration)" if mo["model"] == "cv_continuous" else "m^2/s^4"
    vertical = f", vertically {mo['vertical_q']:g}" if mo.get("vertical_q") is not None else ""
    truth = "the truth flies straight lines, the same in every run" if mo["truth"] == "straight" else "the truth's"
    pooled = ("; detections pooled per receiver (single-frequency network: the illuminator of a detection is "
              "unknown; clutter per receiver list)" if st.get("illuminator_known") is False else "")
    peers = [m for m, v in tr.items() if v.kind == "stonesoup"]
    peers = (f" Stone Soup rows ({', '.join(peers)}): Stone Soup 1.9.1's EKF with its JPDA (every joint event) or "
             "GNN, given the same Pd, clutter density and priors and our motion and bistatic models, the pairs in "
             "turn (pmsr_nn/methods/stonesoup.py); the UKF moments and m best events are ours." if peers else "")
    rate, box = f"Doppler {st['noise'].get('doppler_hz')} Hz", f"Doppler {st['clutter']['doppler_hz']} Hz"
    if "range_rate_mps" in st["noise"]:  # detections of range-rate
        rate, box = f"range-rate {st['noise']['range_rate_mps']} m/s", f"range-rate {st['clutter']['range_rate_mps']} m/s"
    loss = st.get("loss")
    loss = ("" if not loss else f" Loss rule: {loss['successive_scans']} scans dummy-most-probable, or predicted range "
                                f"deviation > {loss['gate_range_sd_m']:g} m.")
    trackers = (f"Trackers: UKF moments, m = {', '.join(map(str, m_best)) or '-'} best events (JPDA), gate probability "
                f"{gate}, CV with q = {st['q']} {unit}{vertical} ({truth}).{loss}")
    if st.get("aircraft"):  # designed flights: the trackers' settings are their rows' options
        limit = "" if st.get("max_range_m") is None else f" and within {st['max_range_m'] / 1e3:g} km of bistatic range"
        trackers = (f"Truth: {len(st['aircraft'])} designed aircraft flights ({', '.join(st['aircraft'])}), each seen "
                    f"above {st['min_altitude_m']:g} m{limit}; the trackers' settings are their options (settings in "
                    "results.json).")
    return [f"{st['scans']} scans of {st['dt_s']} s, {st.get('dimensions', 2)}-D. Transmitters {tx}; receiver at "
            f"{st['receivers'][0]}. Noise: range {st['noise']['range_m']} m, {rate}. Clutter: {st['clutter']['model']}, "
            f"uniform over range {st['clutter']['range_m']} m x {box}{pooled}.", trackers,
            f"OSPA / GOSPA cut-off {st['set_metrics']['c_m']:g} m, order {st['set_metrics']['p']:g}. Position RMSE = "
            f"{results.definitions['rmse_pos_m']}.{peers}"]


def _recipe_lines(results: Results) -> list[str]:
    """The sentences of a scenario on a recipe's sensors and motion (fixed noise, detections)."""
    st = results.settings.sections
    outliers = (f" ({100 * st['noise']['range_outlier_prob']:g} % of range errors with {st['noise']['range_outlier_scale']:g}x "
                "the deviation; the filters assume the nominal one)" if "range_outlier_prob" in st["noise"] else "")
    lines = [f"Noise: {st['noise']['range_m']} m, {st['noise']['range_rate_mps']} m/s, {st['noise']['azimuth_deg']} deg{outliers}; "
             f"recipe `{Path(st['recipe']).name}` ({st['variant']} variant, dt {st['dt_s']} s, q {st['q_psd']:g} m^2/s^5). "
             f"Position RMSE = {results.definitions['rmse_pos_m']} (warm-up {st['warmup_steps']} steps). "
             "The pooled RMSE is given beside it; it weighs late, large errors more."]
    if "detections" in st:
        d = st["detections"]
        over = " x ".join(d["components"])
        seen = (f" and reports {d['clutter_per_scan']:g} clutter points per scan ({d['clutter_model']}) uniform over "
                f"{over}")
        if d.get("illuminator_known") is False:
            seen = (f"; each of the {d['receivers']} receivers reports its pairs' detections in one list, the transmitter "
                    f"of each unknown (a single-frequency network), with {d['clutter_per_scan']:g} clutter points per "
                    f"list and scan ({d['clutter_model']}) uniform over {over}; rows marked \"pooled per receiver\" "
                    "read those lists, the other detection rows each pair's own list (the illuminator given; the "
                    "clutter split evenly over a receiver's pairs)")
        lines.append(f"Detections: every one of the {d['sensors']} transmitter-receiver pairs detects each living target "
                     f"with probability {d['pd']}{seen}; the single-target methods read "
                     "each target's own clean stream (association known). Random streams: "
                     f"{st.get('random_streams', 'per_block')}; OSPA / GOSPA cut-off {st['set_metrics']['c_m']:g} m, "
                     f"order {st['set_metrics']['p']:g}.")
    return lines


def setting_lines(results: Results) -> list[str]:
    """What was simulated, in one paragraph (quoting the settings of results.json): the scenario's
    own world or its recipe, the noise, the detections and trackers, the set metrics."""
    st = results.settings.sections
    if "rd_maps" in st and all(m.reads == "rd_maps" for m in results.settings.methods.values()):  # maps only
        return [f"Every method reads the range-Doppler maps of the scenario's rd_maps section (each case's maps in the "
                f"track-before-detect section below); recipe `{Path(st['recipe']).name}` (dt {st['dt_s']} s, the frames). "
                f"Position RMSE = {results.definitions['rmse_pos_m']} (warm-up {st['warmup_steps']} steps), over each "
                f"method's tracks matched to the target; OSPA / GOSPA cut-off {st['set_metrics']['c_m']:g} m, order "
                f"{st['set_metrics']['p']:g}.", ""]
    return [" ".join(_world_lines(results) if "scans" in st else _recipe_lines(results)), ""]


def write_report(res: Results | dict, out: Path, examples: dict, geometry, ref: dict | None, ref_timing: dict | None,
                 ref_label: str = "paper") -> list[Path]:
    """Write ``out/report.md`` and the figures of any scenario's results; returns the files
    written. ``examples``: run 0's truth and estimates per case (m); ``geometry``: the sensors;
    ``ref`` / ``ref_timing``: the paper's accuracy and run-time tables (None without)."""
    results = Results.of(res)
    single_case = bool(ref) and not any(isinstance(v, dict) for v in ref.values())
    cases = results.cases
    sweep = results.settings.sweep
    figures = plot_rmse(results, out) + plot_set_metrics(results, out)
    per_row = [n for n in drawn_cases(results) if plot_case_tracks(results, examples, n, out / f"{n}_tracks.png")]
    figures += [out / f"{n}_tracks.png" for n in per_row]
    figures.append(plot_trajectories(results, examples, geometry, out / "trajectories.png", skip=per_row))
    figures += write_front_end_outputs(results, examples, out)
    plane_lines, plane_figures = plane_report(results, examples, out)
    figures += plane_figures
    if sweep != "none":
        figures.append(plot_sweep(results, out / f"sweep_{sweep}.png"))
    env = results.environment
    lines = [f"# {results.scenario}: {results.mc_runs} Monte Carlo runs per case, seed {results.seed}", ""]
    if env.get("preview_of_runs"):  # pmsr merge --runs: the first runs of a recording still running
        lines += [f"**A preview: the first {results.mc_runs} of the scenario's {env['preview_of_runs']} runs**, merged "
                  "from the shards of a recording in progress; every figure and error below is of these runs.", ""]
    if env.get("per_run_rescored_blocks"):  # pmsr merge of blocks made before the set scans' fix (issue 55)
        lines += [f"Blocks {env['per_run_rescored_blocks']} were scored over other scans than the set scans (made before "
                  "issue 55's fix); the merge re-derived their per-run GOSPA and OSPA (Monte Carlo errors, run "
                  "quantiles, paired comparisons) from their per-scan sums over the set scans.", ""]
    if results.description:
        lines += [results.description.strip(), ""]
    lines += setting_lines(results)
    lines += ["## Position RMSE (m)" + (", ours beside the paper's" if ref else ""), ""]
    lines += summary_table(results, ref, ref_label, single_case)
    lines.append("")
    lines += space_note(results)
    if ref:
        info = results.reference
        lines += [f"Columns marked *{ref_label}* are the paper's numbers, read from `{Path(info['file']).name}` "
                  f"(`{info['table']}`) for reference only; the paper's trajectories are not given numerically, so "
                  "they compare in order of magnitude and ranking, not digit by digit.", ""]
    lines += flag_paragraphs(results)
    if sweep != "none":
        lines += ["## Sweep", "", *sweep_table(results, ref_timing, ref_label)]
    lines += front_end_tables(results)
    tbd = rd_maps_lines(results, out, examples)  # rows that read range-Doppler maps: their own section
    figures += [f for f in sorted(out.glob("*.png")) if tbd and f not in figures]
    lines += tbd
    mt = multi_target_tables(results, ref_timing, ref_label)
    if mt:
        lines += ["## Multi-target figures", "", *mt, *per_target_tables(results, ref_label)]
    lines += plane_lines
    lines += learned_tables(results) if results.designed else []
    lines += tuning_tables(results)
    if results.designed:
        lines += ["## Per case", ""]
        for name, case in cases.items():
            lines += case_table(name, case, ref, ref_label, single_case) + [""]
            lines += [f"![RMSE vs time]({name}_rmse.png)", ""]
        lines += ["Causal methods are compared with the filtering bound, methods that look ahead with the smoothing "
                  "bound. Diverged runs are counted and kept in the averages.", ""]
    elif sweep == "none":
        lines += ["## RMSE per target vs time", ""] + [f"![{n}]({n}_rmse.png)" for n in cases] + [""]
    lines += ["## Trajectories", "", "![trajectories](trajectories.png)", ""]
    for n in per_row:
        lines += [f"Run 0's tracks of every row, `{n}` (`{n}_tracks.png`): the truth in grey, each track mapped to a "
                  "target (the track table's mapping) in its own colour; the report's false tracks (never mapped) "
                  "split into duplicates (within the cut-off of a living target at half their scans or more: beside "
                  "a target another track holds) and false tracks (the rest), each marked at its first scan.", "",
                  f"![tracks of every row, {n}]({n}_tracks.png)", ""]
    lines += ["## Run time (measured in this run)", ""]
    lines += timing_table(results, ref_timing, ref_label)
    lines += ["", f"Environment: pmsr_nn {env['pmsr_nn']}, torch {env['torch']}, {env['machine']}, device {env['device']}, "
              f"{env['threads']} threads, {env['date']}, commit {env['commit']}. Command: `{env['command']}`.", "",
              "## Definitions", ""]
    lines += [f"- `{k}`: {v}" for k, v in results.definitions.items()]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return [out / "report.md", *figures]
