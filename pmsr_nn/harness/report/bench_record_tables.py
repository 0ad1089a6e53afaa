"""The tables of benchmarks/RESULTS.md written from a benchmark's JSON (benchmarks/results/): one
function per table, of the loaded record (or records, in its marker's order), returning its lines
(:mod:`.record_tables` places them)."""

from __future__ import annotations

import json
from pathlib import Path

from .record_cells import fixed, row, scientific, significant

PAPER_TABLES = Path(__file__).resolve().parents[3] / "evaluate/reference/paper_tables.json"


SIMULATE = "benchmarks/results/simulate_throughput.json"
FILTERS = "benchmarks/results/bench_filters.json"
SI_KF = "benchmarks/results/bench_si_kf.json"
PARTICLE = "benchmarks/results/bench_particle.json"


def simulate_throughput(rec: dict) -> list[str]:
    """`pmsr simulate` throughput and memory per variant and size (benchmarks/simulate_throughput.py)."""
    out = ["| variant | tracks x 1000 s | track-steps/s | wall s | MB on disk | raw write of same bytes, s "
           "| ratio to raw write | acceptance | left envelope | peak RSS MiB |",
           "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rec["rows"]:
        out.append(row([r["variant"], str(r["tracks"]), f"{r['track_steps_per_s'] / 1e6:.2f} M", fixed(r["seconds"], 2),
                        f"{r['bytes'] / 1e6:.0f}", fixed(r["raw_write_seconds"], 2),
                        f"{r['seconds'] / r['raw_write_seconds']:.1f}x", f"{100 * r['acceptance']:.1f}%",
                        f"{100 * r['fraction_left_envelope']:.1f}%", f"{r['peak_rss_mib']:.0f}"]))
    return out


def bench_filters(rec: dict) -> list[str]:
    """The batched EKF / UKF against filterpy, as benchmarks/bench_filters.py prints it."""
    out = ["```"]
    for f in ("ekf", "ukf"):
        out.append(f"{f}: {rec['tracks']} tracks x {rec['steps']} steps in {rec[f + '_seconds']:.2f} s = "
                   f"{rec[f + '_track_steps_per_s'] / 1e6:.2f} M track-steps/s; filterpy "
                   f"{rec[f + '_filterpy_ms_per_track']:.1f} ms/track -> speed-up {rec[f + '_speedup_vs_filterpy']:.0f}x; "
                   f"max |diff| {rec[f + '_max_abs_diff_vs_filterpy']:.2e}")
    return out + ["```"]


def bench_si_kf(rec: dict) -> list[str]:
    """SI fixes and SI+KF, plain and with two Gauss-Newton steps (benchmarks/bench_si_kf.py)."""
    out = ["```"]
    for key in ("si", "si_gn2"):
        r = rec[key]
        out.append(f"{key + ':':<7} position RMSE fixes {r['fix_rmse_m']:5.1f} m, SI+KF {r['kf_rmse_m']:5.1f} m "
                   f"(mean NIS {r['kf_mean_nis']:.2f}); fixes {r['fix_track_steps_per_s'] / 1e6:.2f} M track-steps/s, "
                   f"SI+KF {r['si_kf_track_steps_per_s'] / 1e3:.0f} k track-steps/s")
    return out + ["```"]


def bench_particle(rec: dict) -> list[str]:
    """The bootstrap particle filter beside the UKF on the same tracks (benchmarks/bench_particle.py)."""
    n = f"{rec['tracks']} tracks x {rec['steps']} steps"
    return ["```",
            f"ukf: {n} in {rec['ukf_seconds']:.2f} s = {rec['ukf_track_steps_per_s']:,.0f} track-steps/s; "
            f"RMSE pos {rec['ukf_rmse_pos_m']:.2f} m, vel {rec['ukf_rmse_vel_mps']:.3f} m/s",
            f"pf ({rec['particles']} particles): {rec['pf_seconds']:.2f} s = {rec['pf_track_steps_per_s']:,.0f} "
            f"track-steps/s ({rec['pf_particle_steps_per_s'] / 1e6:.2f} M particle-steps/s, "
            f"{rec['pf_seconds'] / rec['ukf_seconds']:.0f}x the UKF's time); RMSE pos {rec['pf_rmse_pos_m']:.2f} m, "
            f"vel {rec['pf_rmse_vel_mps']:.3f} m/s",
            f"pf: mean ESS {100 * rec['pf_mean_ess_fraction']:.1f}% of the particles, resampled at "
            f"{100 * rec['pf_resampled_fraction']:.1f}% of track-steps, lost {rec['pf_lost_tracks']} of {rec['tracks']} tracks",
            "```"]


LEARNED = "benchmarks/results/bench_learned.json"
_LEARNED_ROWS = [("MDFNN (Table 2, paper inputs)", "MDFNN"),
                 ("MDFNN (Table 2, local inputs, residual output, per-channel taps)", "MDFNN-local"),
                 ("MDFNN local, compact 128 / 96 / 128 (`models/mdfnn_local.yaml`)", "MDFNN-local-compact"),
                 ("KalmanNet-style, GRU 64 (`models/kalmannet.yaml`)", "KalmanNet"),
                 ("DFNN", "DFNN"), ("LSTM-256", "LSTM-256")]


def bench_learned(rec: dict) -> list[str]:
    """Training windows/s of each network and the MDFNN's inference beside the UKF's
    (benchmarks/bench_learned.py, one precision)."""
    out = ["| network | windows/s | vs Table-2 MDFNN |", "| --- | ---: | ---: |"]
    for label, key in _LEARNED_ROWS:
        out.append(row([label, f"{rec['training_windows_per_s'][key]:.0f}",
                        f"{rec['training_speed_over_mdfnn_fp32'][key]:.1f}x"]))
    inf = rec["inference"]
    out.append(row([f"inference: MDFNN {scientific(inf['mdfnn_track_steps_per_s'])} track-steps/s against the UKF's "
                    f"{scientific(inf['ukf_track_steps_per_s'])} in the same run", "", f"{inf['mdfnn_over_ukf_speed']:.2f}x"]))
    return out


PMHT_BENCH = "benchmarks/results/bench_pmht.json"
_PMHT_ROWS = [("PMHT-3D (pooled lists, illuminator unknown)", "PMHT-3D"), ("PMHT (per-pair lists)", "PMHT")]


def bench_pmht(rec: dict) -> list[str]:
    """Seconds per 200-scan run against EM iterations, the paper's Table 3 in brackets, and the
    batched time per run (benchmarks/bench_pmht.py)."""
    iterations = list(rec["methods"][_PMHT_ROWS[0][1]]["serial_s_per_run_vs_em"])
    out = ["| tracker | " + " | ".join(iterations) + " | batched, 10 runs per call, 6 EM (s / run) |",
           "|---|" + "---:|" * (len(iterations) + 1)]
    for label, key in _PMHT_ROWS:
        m = rec["methods"][key]
        out.append(row([label] + [f"{m['serial_s_per_run_vs_em'][i]:.2f} ({m['paper_s_per_run_vs_em'][i]})"
                                  for i in iterations] + [fixed(m["batched_s_per_run_6em"], 2)]))
    return out


MSJPDA = "benchmarks/results/bench_msjpda.json"
_MSJPDA_ROWS = [("S-MSJPDA", "S-MSJPDA"), ("P-MSJPDA (m = 10)", "P-MSJPDA"), ("P-MSJPDA (m = 100)", "P-MSJPDA m=100"),
                ("true-assignment UKF", "true assignment")]


def bench_msjpda_nominal(rec: dict) -> list[str]:
    """S- and P-MSJPDA seconds per run, serial and batched, and P/S beside the paper's: the
    2026-11-22 run every tracker was timed in, kept as ``previous_record`` of the file."""
    prev = rec["previous_record"]
    out = ["| tracker | serial s / run (mean, median) | batched s / run (10 runs per call) | paper s / run (MATLAB) |",
           "|---|---:|---:|---:|"]
    for label, key in _MSJPDA_ROWS:
        m = prev["methods"][key]
        paper = m["paper_s_per_run"]
        out.append(row([label, f"{m['serial_s_per_run_mean']:.3f}, {m['serial_s_per_run_median']:.3f}",
                        fixed(m["batched_s_per_run"], 3), "" if paper is None else fixed(paper, 2)]))
    for label, key in (("P (m = 10) / S", "P-MSJPDA"), ("P (m = 100) / S", "P-MSJPDA m=100")):
        r = prev["p_over_s"][key]
        out.append(row([label, f"{r['serial_s_per_run_mean']:.1f}x", f"{r['batched_s_per_run']:.1f}x",
                        f"{prev['paper_p_over_s']:.1f}x"]))
    return out


def bench_msjpda_rounds(rec: dict) -> list[str]:
    """S-MSJPDA's batched seconds per run in a block of 100, per round and the rounds' median,
    before (the file's ``before_6b20c70``) and after (issue 37's batched association)."""
    rounds = rec["rounds_batched_s_per_run"]
    before, after = sorted(rounds["before"])[1], sorted(rounds["after"])[1]
    assert after == rec["methods"]["S-MSJPDA"]["batched_s_per_run"], "the file's figures are its median round's"
    return ["| S-MSJPDA, block of 100 runs | before (6b20c70) | after |",
            "|---|---:|---:|",
            row(["batched s / run, per round", ", ".join(fixed(x, 3) for x in rounds["before"]),
                 ", ".join(fixed(x, 3) for x in rounds["after"])]),
            row(["batched s / run, median of the rounds", fixed(before, 3),
                 f"{after:.3f} ({before / after:.0f}x faster)"])]


MSJPDA_EXACT = "benchmarks/results/bench_msjpda_exact.json"
_EXACT_ROWS = [("S-MSJPDA", "S-MSJPDA"), ("P-MSJPDA (m = 10, exact)", "P-MSJPDA"),
               ("P-MSJPDA (m = 10, relaxation)", "P-MSJPDA relaxation"), ("P-MSJPDA (m = 100, exact)", "P-MSJPDA m=100"),
               ("true-assignment UKF", "true assignment")]


def bench_msjpda_exact(rec: dict) -> list[str]:
    """S-MSJPDA and P-MSJPDA with exactly ranked events or the relaxation: seconds per run, serial
    (mean) and batched (median of the passes)."""
    out = [f"| tracker | serial s / run (mean of {rec['serial_runs']}) "
           f"| batched s / run ({rec['block']} runs per call, median of {rec['repeats']}) |",
           "|---|---:|---:|"]
    for label, key in _EXACT_ROWS:
        m = rec["methods"][key]
        out.append(row([label, fixed(m["serial_s_per_run_mean"], 3), fixed(m["batched_s_per_run"], 3)]))
    return out


TBD_BENCH = "benchmarks/results/bench_tbd.json"


def bench_tbd(rec: dict) -> list[str]:
    """Seconds per run of the modified ICMB per sub-area beside the seed's Table 2 (its MATLAB
    times, from the paper's tables) and their ratio (two significant figures, whole from 100)."""
    seed = json.loads(PAPER_TABLES.read_text())["remotesensing2020_icmb"]["table2_subarea"]
    theirs = dict(zip(seed["size"], seed["computation_time_s"]))
    out = ["| sub-area | ours, s per run | the seed (MATLAB), s per run | seed / ours |", "|---|---:|---:|---:|"]
    for size, ours in rec["subarea_seconds_per_run"].items():
        label = f"whole map ({rec['map_cells'][0]} rows x 11 columns the triangle reaches)" if size == "full" else size
        cell = fixed(ours, 2 if ours < 10 else 1)
        ratio = theirs[size] / ours
        out.append(row([label, f"**{cell}**" if size == "5x5" else cell, fixed(theirs[size], 2),
                        significant(ratio, 2) if ratio < 100 else fixed(ratio, 0)]))
    return out


HARNESS = "benchmarks/results/bench_harness_overhead.json"
_HARNESS_LABELS = {"fitee2023_three_trajectories.yaml": "fitee2023_three_trajectories, trajectory_1",
                   "shared_drones.yaml": "shared_drones (3 drones, 520 scans)"}


def bench_harness_overhead(rec: dict) -> list[str]:
    """The runner against direct tracker calls on the same draws: every repeat's seconds both ways
    and the ratio of the medians."""
    first = rec["scenarios"][0]
    n = len(first["harness_s"])
    out = [f"| scenario ({first['runs']} runs in {first['runs'] // first['block_runs']} blocks) | methods "
           f"| harness s ({n} repeats) | direct s ({n} repeats) | ratio of medians |",
           "|---|---|---|---|---:|"]
    for sc in rec["scenarios"]:
        methods = ", ".join(m.replace(" [seed ", " s").replace("]", "") for m in sc["methods"])
        out.append(row([_HARNESS_LABELS[sc["scenario"]], methods, " ".join(fixed(x, 2) for x in sc["harness_s"]),
                        " ".join(fixed(x, 2) for x in sc["direct_s"]), fixed(sc["ratio_of_medians"], 3)]))
    return out


ONNX = "benchmarks/results/bench_onnx.json"
_ONNX_LABELS = {"mdfnn": "mdfnn (Table 2)", "rnn": "rnn (LSTM 256)", "mdfnn_local_s0": "mdfnn_local_s0 (fixes as input)"}


def bench_onnx(rec: dict) -> list[str]:
    """Each released tracker in torch and in onnxruntime: scans per second, their ratio and the
    largest difference of the estimates (of a column's span)."""
    out = ["| checkpoint | torch (scans/s) | onnxruntime (scans/s) | onnxruntime / torch "
           "| largest difference (of a column's span) |",
           "|---|---:|---:|---:|---:|"]
    for r in rec["rows"]:
        label = _ONNX_LABELS.get(r["checkpoint"], r["checkpoint"])
        if r["kind"] == "kalmannet":
            label = f"{r['checkpoint']} (step graph, {r['scans'] - 1} calls)"
        out.append(row([label, f"{r['torch_scans_per_s']:,.0f}", f"{r['onnxruntime_scans_per_s']:,.0f}",
                        fixed(r["onnxruntime_over_torch"], 2), scientific(r["max_diff_over_span"], 1)]))
    return out


PHD = "benchmarks/results/bench_phd.json"


def bench_phd(rec: dict) -> list[str]:
    """The SMC-PHD's seconds per run of the benchmark scene, one run, batched and with GTDA
    labelling, against the real-time target."""
    out = [f"| | s per {rec['scans']}-scan run | ms per scan | x real time | target (< {rec['target_seconds_per_run']:.0f} s) |",
           "|---|---:|---:|---:|---|"]
    for label, key in (("SMC-PHD, one run", "single"),
                       (f"SMC-PHD, {rec['batched']['runs_per_call']} runs batched in one call (per run)", "batched"),
                       ("SMC-PHD + GTDA labelling, one run", "with_gtda")):
        r = rec[key]
        out.append(row([label, fixed(r["seconds_per_run"], 2), fixed(1e3 * r["seconds_per_scan"], 1),
                        fixed(r["real_time_factor"], 1), "met" if r["target_met"] else "not met"]))
    return out


FRONT_END = "benchmarks/results/bench_front_end.json"


def bench_front_end(rec: dict) -> list[str]:
    """One CPI through the FM chain: ms per CPI and times real time, one pair and batched, and the
    stages alone."""
    o = rec["ours"]
    st = o["stages_seconds"]
    stages = (f"stages alone: ECA {1e3 * st['eca']:.1f}, 2D-CCF {1e3 * st['ccf_batches']:.1f}, "
              f"OS-CFAR {1e3 * st['os_cfar']:.1f}, centroids {1e3 * st['centroids']:.1f}")
    return ["| | ms per CPI (one pair) | x real time |", "|---|---:|---:|",
            row(["ours, whole chain, one pair per call", fixed(1e3 * o["seconds_per_cpi_one_pair"], 1),
                 fixed(o["x_real_time_one_pair"], 1)]),
            row(["ours, whole chain, 6 pairs per call (per pair)", fixed(1e3 * o["seconds_per_cpi_batch_of_6"], 1),
                 fixed(o["x_real_time_batched"], 1)]),
            row([stages, "", ""])]


FAULT_CENSUS = "benchmarks/results/fault_census_round3.json"
CENSUS_CLASSES = ("data_loss", "hang", "traceback", "silent_wrong", "leftover", "messy_refusal", "clean_refusal", "ok")


def fault_census(rec: dict) -> list[str]:
    """The fault census's outcomes per command (benchmarks/fault_census.py: every case of
    tests/faults/cases.py as a subprocess), one column per class, '.' for none."""
    by = rec["meta"]["by_command"]
    return _census_table([(command, [str(counts.get(c, ".")) for c in CENSUS_CLASSES] + [str(sum(counts.values()))])
                          for command, counts in [*by.items(), ("**all**", rec["meta"]["counts"])]])


def _census_table(rows: list[tuple[str, list[str]]]) -> list[str]:
    """A census table: a column per outcome class and the cases, a row per command (the last, the
    totals, in bold but for its '.' cells)."""
    out = ["| command | " + " | ".join(c.replace("_", " ") for c in CENSUS_CLASSES) + " | cases |",
           "|---|" + "---:|" * (len(CENSUS_CLASSES) + 1)]
    for i, (command, cells) in enumerate(rows):
        if i == len(rows) - 1:
            cells = [c if c == "." else f"**{c}**" for c in cells]
        out.append(row([command, *cells]))
    return out


LEARNED_GPU = "benchmarks/results/bench_learned_gpu.json"
LEARNED_GPU_HOST = "benchmarks/results/bench_learned_gpu_host_cpu.json"
_LEARNED_GPU_ROWS = [("MDFNN (Table 2)", "MDFNN"), ("DFNN", "DFNN"), ("LSTM-256", "LSTM-256"),
                     ("MDFNN (Table 2, local inputs)", "MDFNN-local"),
                     ("MDFNN local, compact (`models/mdfnn_local.yaml`)", "MDFNN-local-compact"),
                     ("KalmanNet-style, GRU 64 (`models/kalmannet.yaml`)", "KalmanNet")]


def bench_learned_gpu(gpu: dict, host: dict) -> list[str]:
    """Training windows/s on the GPU (float32, bf16) beside its host's CPU (float32), their ratio, and
    the MDFNN's inference against the UKF on each (two runs of benchmarks/bench_learned.py)."""
    out = ["| network | H100 float32 (windows/s) | H100 bf16 (windows/s) | host CPU, 16 threads, float32 (windows/s) "
           "| H100 / CPU |", "| --- | ---: | ---: | ---: | ---: |"]
    g, h = gpu["training_windows_per_s"], host["training_windows_per_s"]
    for label, key in _LEARNED_GPU_ROWS:
        out.append(row([label, f"{g[key]:,.0f}", f"{g[key + ' bf16']:,.0f}", f"{h[key]:,.0f}",
                        f"{significant(g[key] / h[key], 2)}x"]))
    gi, hi = gpu["inference"], host["inference"]
    out.append(row([f"inference: MDFNN, {gi['tracks']} tracks x {gi['steps']} scans, against the UKF (CPU) in the same run",
                    f"{scientific(gi['mdfnn_track_steps_per_s'])} track-steps/s", "",
                    f"{scientific(hi['mdfnn_track_steps_per_s'])} ({hi['tracks']} tracks)",
                    f"MDFNN {gi['mdfnn_over_ukf_speed']:.0f}x the UKF on the GPU, "
                    f"{significant(hi['mdfnn_over_ukf_speed'], 2)}x on the {host['threads']}-thread CPU"]))
    return out


TBD_ISSUE37 = tuple(f"benchmarks/results/bench_tbd_issue37_{when}_round{r}.json"
                    for when in ("before", "after") for r in (1, 2))
TBD_ISSUE37_SNR = tuple(f"benchmarks/results/bench_tbd_issue37_snr_round{r}.json" for r in (1, 2))


def bench_tbd_issue37(before1: dict, before2: dict, after1: dict, after2: dict) -> list[str]:
    """Seconds per run per sub-area before and after issue 37's likelihood, two rounds each
    (the after 5x5 in bold), and the 5x5 with five runs per call."""
    out = ["| sub-area | before, s per run (rounds 1, 2) | after, s per run (rounds 1, 2) |", "|---|---|---|"]
    for size in before1["subarea_seconds_per_run"]:
        before = ", ".join(fixed(r["subarea_seconds_per_run"][size], 2) for r in (before1, before2))
        after = ", ".join(fixed(r["subarea_seconds_per_run"][size], 2) for r in (after1, after2))
        out.append(row([size, before, f"**{after}**" if size == "5x5" else after]))
    out.append(row(["5x5, 5 runs per call (per run)",
                    ", ".join(fixed(r["batched_seconds_per_run"], 2) for r in (before1, before2)),
                    ", ".join(fixed(r["batched_seconds_per_run"], 2) for r in (after1, after2))]))
    return out


def bench_tbd_issue37_snr(round1: dict, round2: dict) -> list[str]:
    """5x5 seconds per run with the bias-corrected SNR estimate and the seed's, one and five runs per
    call, two rounds."""
    out = ["| 5x5, s per run | round 1 | round 2 |", "|---|---:|---:|"]
    for label, key in (("bias-corrected estimate, one run per call", None),
                       ("the seed's estimate, one run per call", "seed_max_estimate_5x5_seconds_per_run"),
                       ("bias-corrected estimate, 5 runs per call", "batched_seconds_per_run"),
                       ("the seed's estimate, 5 runs per call", "seed_max_estimate_batched_seconds_per_run")):
        out.append(row([label] + [fixed(r["subarea_seconds_per_run"]["5x5"] if key is None else r[key], 2)
                                  for r in (round1, round2)]))
    return out


FAULT_CENSUS_BEFORE = "benchmarks/results/fault_census_before.json"
FAULT_CENSUS_AFTER = "benchmarks/results/fault_census_after.json"


def fault_census_before_after(before: dict, after: dict) -> list[str]:
    """The first fault census's outcomes per command before and after the fixes ('b → a', '.' where
    both are none), the totals in bold."""
    rows = [(c, before["meta"]["by_command"][c], after["meta"]["by_command"][c]) for c in after["meta"]["by_command"]]
    return _census_table([(command, ["." if not b.get(c) and not a.get(c) else f"{b.get(c, 0)} → {a.get(c, 0)}"
                                     for c in CENSUS_CLASSES] + [str(sum(a.values()))])
                          for command, b, a in [*rows, ("**all**", before["meta"]["counts"], after["meta"]["counts"])]])


SET_TRACKER_GPU = "benchmarks/results/set_tracker_h200.json"
SET_TRACKER_CPU = "benchmarks/results/set_tracker_cpu.json"
SET_TRACKER_COMMIT = "4699b3d"
"""The commit that last held the set tracker and benchmarks/bench_set_tracker.py (removed from the
package under issue 56); the records' commands ran that script."""


def bench_set_tracker(gpu: dict, cpu: dict) -> list[str]:
    """The set tracker's seconds per run of 240 scans on the device machine's GPU and on the 2-core CPU
    (benchmarks/bench_set_tracker.py, one JSON each; the script is at commit ``SET_TRACKER_COMMIT``);
    the commands as the document gives them."""
    g, c = gpu["cuda"]["seconds_per_run"], cpu["cpu"]["seconds_per_run"]
    return ["| device | command (at commit " + SET_TRACKER_COMMIT + "), date | s per run of 240 scans | record |",
            "|---|---|---:|---|",
            row([f"{gpu['cuda']['name']} (device machine, torch {gpu['torch']})",
                 "`python benchmarks/bench_set_tracker.py --checkpoint runs/set_tracker_s0/tracker.pt --runs "
                 f"{gpu['runs']} --repeats 3 --devices cuda`, {gpu['date']}, right after the training in the same device call",
                 fixed(g, 3), f"`results/{Path(SET_TRACKER_GPU).name}`"]),
            row([f"2-core Intel Xeon (AVX-512), {cpu['threads']} threads, nothing else running",
                 f"`OMP_NUM_THREADS={cpu['threads']} python benchmarks/bench_set_tracker.py --checkpoint "
                 f"runs/set_tracker_s2/tracker.pt --runs {cpu['runs']} --repeats 2 --devices cpu`, {cpu['date']}",
                 fixed(c, 1), f"`results/{Path(SET_TRACKER_CPU).name}`"])]


def bench_pmht_stonesoup(rec: dict) -> list[str]:
    """Stone Soup's PMHTTracker against ours on one pair (bench_pmht.py's ``stonesoup`` entry)."""
    s = rec["stonesoup"]
    return ["| tracker | s / run | position RMSE (m), scans 10+ |", "|---|---:|---:|",
            row(["Stone Soup `PMHTTracker`", fixed(s["stonesoup_s_per_run"], 2), fixed(s["stonesoup_rmse_pos_m"], 0)]),
            row(["ours (`pmht`, one pair)", fixed(s["ours_s_per_run"], 3), fixed(s["ours_rmse_pos_m"], 0)])]


LEARNED_FIRST = "benchmarks/results/bench_learned_2026-11-21.json"


def bench_learned_first(rec: dict) -> list[str]:
    """The first bench_learned.py run (MDFNN, DFNN, LSTM training; MDFNN inference beside the UKF)."""
    t, inf = rec["training_windows_per_s"], rec["inference"]
    return ["| | figure |", "| --- | --- |",
            row([f"training, MDFNN (Table 2), batch {rec['batch']} x {rec['window']} scans", f"{t['MDFNN']:,.0f} windows/s"]),
            row(["training, DFNN", f"{t['DFNN']:,.0f} windows/s"]),
            row(["training, LSTM-256", f"{t['LSTM-256']:,.0f} windows/s"]),
            row([f"inference, MDFNN, {inf['tracks']} tracks x {inf['steps']} scans (spliced windows, stride {inf['stride']})",
                 f"{scientific(inf['mdfnn_track_steps_per_s'])} track-steps/s"]),
            row(["inference, batched UKF (float64), same tracks, same run",
                 f"{scientific(inf['ukf_track_steps_per_s'])} track-steps/s"]),
            row(["MDFNN / UKF speed", f"{inf['mdfnn_over_ukf_speed']:.2f}x"])]
