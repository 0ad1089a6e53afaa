"""The tables of evaluate/RESULTS.md written from the records of the multi-target studies
(evaluate/results/STUDY/results.json): one_sky, shared_drones, the learned trackers on detections
and the burn-in of the innovation bias test, the JEIT 2021 PMHT study, the track-before-detect,
SMC-PHD and FM front-end studies (the MSJPDA study's: :mod:`.msjpda_record_tables`). One function per table, of the loaded record,
returning its lines; :mod:`.record_tables` places them between the documents' markers. Row labels
and what a row reads are the document's choice and sit here; every number is the record's."""

from __future__ import annotations

import json

from .bench_record_tables import PAPER_TABLES
from .record_cells import fixed, pm, row, significant


def _cases(rec: dict) -> list[tuple[str, dict]]:
    return list(rec["cases"].items())


# ---------------------------------------------------------------- one sky

ONE_SKY = "evaluate/results/one_sky/results.json"

_ONE_SKY_ROWS = [  # (row, what it reads): the reads column is the scenario's wiring, not a figure
    ("EKF", "own stream"), ("UKF", "own stream"), ("IMM", "own stream"),
    ("KalmanNet [seed 0]", "own stream"), ("MDFNN local [seed 0]", "own stream"), ("PCRB", "own stream"),
    ("S-MSJPDA (oracle births)", "per pair, oracle births"), ("S-MSJPDA", "per pair"), ("P-MSJPDA", "per pair"),
    ("PMHT", "per pair"), ("PMHT-3D", "**pooled per receiver**"), ("SMC-PHD + GTDA", "per pair"),
    ("modified ICMB", "maps"), ("detect-then-track (OS-CFAR 1e-4)", "maps"), ("Stone Soup JPDA", "per pair"),
]


def _paired_rows(group: dict, header: str) -> list[str]:
    """A ``set_comparisons`` group: each row minus the group's best, GOSPA and OSPA, with verdicts."""
    out = [f"| {header}, minus {group['reference']} | GOSPA difference (m) | verdict | OSPA difference (m) | verdict |",
           "|---|---:|---|---:|---|"]
    for name, r in group["rows"].items():
        g, o = r["gospa_m"], r["ospa_m"]
        out.append(row([name, f"{g['difference']:+.1f} ± {g['se']:.1f}", g["verdict"],
                        f"{o['difference']:+.1f} ± {o['se']:.1f}", o["verdict"]]))
    return out


def one_sky_paired_own_tracks(rec: dict) -> list[str]:
    """one_sky's rows that start their own tracks, paired against the best of them."""
    (_, case), = _cases(rec)
    (group,) = [g for g in case["set_comparisons"] if g["group"] == "start their own tracks"]
    return _paired_rows(group, "rows that start their own tracks")


def one_sky_paired_handed(rec: dict) -> list[str]:
    """one_sky's rows handed their targets, paired against the best of them."""
    (_, case), = _cases(rec)
    (group,) = [g for g in case["set_comparisons"] if g["group"].startswith("are handed their targets")]
    return _paired_rows(group, "rows handed their targets (own streams, oracle births)")


def one_sky_quantiles(rec: dict) -> list[str]:
    """The quantiles of each run's GOSPA for the rows that start their own tracks."""
    (_, case), = _cases(rec)
    (group,) = [g for g in case["set_comparisons"] if g["group"] == "start their own tracks"]
    names = [n for n in case["methods"] if n == group["reference"] or n in group["rows"]]
    out = ["| row | 25 % | median | 75 % | 90 % | worst |", "|---|---:|---:|---:|---:|---:|"]
    for name in names:
        out.append(row([name] + [fixed(q, 1) for q in case["methods"][name]["gospa_run_quantiles_m"]]))
    return out


def one_sky(rec: dict) -> list[str]:
    """evaluate/RESULTS.md's one_sky table: set and track figures of every row, one line each."""
    (_, case), = _cases(rec)
    dt = rec["settings"]["dt_s"]
    out = ["| row | reads | GOSPA (m) ± s.e. | median run's GOSPA (m) | % localisation / missed / false | OSPA (m) ± s.e. "
           "| pos RMSE, matched (m) ± s.e. | confirmed tracks / target | false tracks / run | track loss "
           "| label switches / run | first track after birth (s) | s / run |",
           "|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, reads in _ONE_SKY_ROWS:
        m = case["methods"][name]
        if m["kind"] == "pcrb":
            out.append(row([name, reads, "-", "-", "-", "-", fixed(m["rmse_pos_m"], 1)] + ["-"] * 6))
            continue
        shares = " / ".join(f"{100 * m[f'gospa_{k}_share']:.0f}" for k in ("localisation", "missed", "false"))
        out.append(row([
            name, reads, pm(m["gospa_m"], m["gospa_se_m"]), fixed(m["gospa_median_run_m"], 1), shares,
            pm(m["ospa_m"], m["ospa_se_m"]), pm(m["rmse_pos_m"], m["rmse_pos_se_m"]),
            fixed(m["confirmed_tracks_per_target"], 2), fixed(m["false_tracks_per_run"], 2),
            fixed(m["track_loss_probability"], 2), fixed(m["label_switches_per_run"], 2),
            fixed(m["scans_to_first_track"] * dt, 2), fixed(m["seconds_per_run"], 1)]))
    return out


# ---------------------------------------------------------------- learned trackers on detections (issue 36)

ONE_SKY_HYBRID = "evaluate/results/one_sky_hybrid/results.json"
SHARED_HYBRID = "evaluate/results/shared_drones_hybrid/results.json"
DENSE = "evaluate/results/dense_crossing/results.json"


def _shares(m: dict) -> str:
    return " / ".join(f"{100 * m[f'gospa_{k}_share']:.0f}" for k in ("localisation", "missed", "false"))


def one_sky_hybrid(rec: dict) -> list[str]:
    """The hybrid on one_sky's 50 runs: GOSPA, its run quantiles, paired against the best row
    (``set_comparisons``), matched RMSE, false tracks, seconds per run."""
    (_, case), = _cases(rec)
    (cmp,) = case["set_comparisons"]
    out = ["| row | GOSPA (m) ± s.e. | median run (m) | 75 % / 90 % / worst run (m) | minus the best row, paired (m) "
           "| matched RMSE (m) | false tracks / run | s / run |",
           "|---|---:|---:|---|---:|---:|---:|---:|"]
    for name, m in case["methods"].items():
        if name == cmp["reference"]:
            paired = "best"
        else:
            d = cmp["rows"][name]["gospa_m"]
            paired = f"{d['difference']:+.1f} ± {d['se']:.1f} ({d['verdict']})"
        out.append(row([name, pm(m["gospa_m"], m["gospa_se_m"]), fixed(m["gospa_median_run_m"], 1),
                        " / ".join(fixed(q, 1) for q in m["gospa_run_quantiles_m"][2:]), paired,
                        pm(m["rmse_pos_m"], m["rmse_pos_se_m"]), fixed(m["false_tracks_per_run"], 2),
                        fixed(m["seconds_per_run"], 1)]))
    return out


def shared_drones_hybrid(rec: dict) -> list[str]:
    """The hybrid on shared_drones' 50 runs beside S-MSJPDA from detections (its GOSPA the ratio's
    denominator)."""
    (_, case), = _cases(rec)
    methods = case["methods"]
    base = methods["S-MSJPDA from detections"]["gospa_m"]
    out = ["| method | pos RMSE (m) | GOSPA (m) | % loc. / missed / false | GOSPA / S-MSJPDA's | tracks / target "
           "| false tracks / run | fragm. / run | ANEES | s / run |",
           "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|"]
    for name, m in methods.items():
        out.append(row([name.replace(" from detections", ""), pm(m["rmse_pos_m"], m["rmse_pos_se_m"]),
                        pm(m["gospa_m"], m["gospa_se_m"]), _shares(m), fixed(m["gospa_m"] / base, 2),
                        fixed(m["confirmed_tracks_per_target"], 2), fixed(m["false_tracks_per_run"], 2),
                        fixed(m["fragmentations_per_run"], 2), significant(m["anees"], 3),
                        fixed(m["seconds_per_run"], 2)]))
    return out


def dense_crossing(rec: dict) -> list[str]:
    """dense_crossing's 10 runs: every row's GOSPA (the lowest of the rows that start their own
    tracks in bold), its shares, tracks, false tracks, matched RMSE and seconds per run."""
    (_, case), = _cases(rec)
    methods = case["methods"]
    best = min(m["gospa_m"] for m in methods.values() if m["initiation"] != "oracle")
    out = ["| method | tracks start | GOSPA (m) ± s.e. | % loc. / missed / false | tracks / target "
           "| false tracks / run | pos RMSE (m) | s / run |",
           "|---|---|---:|---|---:|---:|---:|---:|"]
    for name, m in methods.items():
        gospa = pm(m["gospa_m"], m["gospa_se_m"])
        seconds = m["seconds_per_run"]
        out.append(row([name, "oracle" if m["initiation"] == "oracle" else "detections",
                        f"**{gospa}**" if m["gospa_m"] == best else gospa, _shares(m),
                        fixed(m["confirmed_tracks_per_target"], 2), fixed(m["false_tracks_per_run"], 2),
                        fixed(m["rmse_pos_m"], 1), fixed(seconds, 2 if seconds < 10 else 1)]))
    return out


# ---------------------------------------------------------------- PMHT (JEIT 2021)

JEIT = "evaluate/results/jeit2021_pmht/results.json"
_JEIT_ROWS = [("PMHT-3D", "pooled, illuminator unknown"), ("PMHT", "per pair (labels given)"),
              ("PMHT-3D (no annealing)", "pooled, illuminator unknown"), ("S-MSJPDA", "per pair (labels given)"),
              ("UKF smoother (true assignment)", "each target's own detections")]


def jeit_pmht(rec: dict) -> list[str]:
    """evaluate/RESULTS.md's PMHT table: position RMSE ± s.e., velocity RMSE, OSPA, ANEES, label
    switches and seconds per run of each row, and the PCRB (filtering / smoothing / q = 0 floor)."""
    (_, case), = _cases(rec)
    out = ["| method | lists it reads | pos RMSE (m) | vel RMSE (m/s) | OSPA (m, c = 2 km) | NEES / 6 (ANEES) "
           "| label switches / run | s / run |",
           "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, reads in _JEIT_ROWS:
        m = case["methods"][name]
        out.append(row([name, reads, f"{m['rmse_pos_m']:.0f} ± {m['rmse_pos_se_m']:.0f}", fixed(m["rmse_vel_mps"], 2),
                        f"{m['ospa_m']:.0f}", fixed(m["anees"], 2), fixed(m["label_switches_per_run"], 2),
                        fixed(m["seconds_per_run"], 2)]))
    b = case["pcrb"]
    out.append(row(["PCRB filtering / smoothing / q = 0 floor", "",
                    f"{b['pos_m']:.0f} / {b['smoothing_pos_m']:.0f} / {b['q0_pos_m']:.0f}",
                    f"{b['vel_mps']:.2f} / {b['smoothing_vel_mps']:.2f}", "", "", "", ""]))
    return out


# ---------------------------------------------------------------- track-before-detect

TBD = "evaluate/results/remotesensing2020_icmb/results.json"
_TBD_ROWS = [
    ("modified ICMB (online SNR, bias-corrected bootstrap, ascending), 5x5", "modified ICMB"),
    ("modified ICMB (the seed's max estimate), 5x5", "modified ICMB (seed's max estimate)"),
    ("ICMB ascending, known SNRs", "ICMB ascending (known SNR)"),
    ("ICMB descending, known SNRs", "ICMB descending (known SNR)"),
    ("PMB, every map modelled 8 dB", "PMB modelled 8 dB"),
    ("PMB, every map modelled 10 dB", "PMB modelled 10 dB"),
    ("detect-then-track, 2-D OS-CFAR at Pfa 1e-4 per cell", "detect-then-track (OS-CFAR 1e-4)"),
]


def tbd_mixed(rec: dict) -> list[str]:
    """evaluate/RESULTS.md's track-before-detect table on the mixed-SNR maps: detected-frame rates
    (frames 5-8 one by one, frames 9-16 averaged), errors at the last frame, OSPA, seconds per run."""
    methods = rec["cases"]["mixed"]["methods"]
    out = ["| method | detected % | frames 5-8 | frames 9-16 | median / RMS position error m | OSPA m | s per run |",
           "|---|---:|---|---:|---:|---:|---:|"]
    for label, name in _TBD_ROWS:
        t = methods[name]["tbd"]
        rate = t["detected_frame_rate"]
        out.append(row([label, f"{100 * t['detected_rate_present']:.1f}",
                        ", ".join(f"{100 * x:.0f}" for x in rate[4:8]), f"{100 * sum(rate[8:16]) / 8:.1f}",
                        f"{t['median_pos_err_last_present_m']:.0f} / {t['rms_pos_last_present_m']:.0f}",
                        f"{t['ospa_mean_m']:.0f}", fixed(methods[name]["seconds_per_run"], 2)]))
    return out


# ---------------------------------------------------------------- shared drones (issue 34)

SHARED = "evaluate/results/shared_drones/results.json"


def shared_drones(rec: dict) -> list[str]:
    """shared_drones' 50 runs: every row's how tracks start, matched RMSE, GOSPA and its shares,
    track counts, first track after birth, track loss, fragmentations, seconds per run."""
    (_, case), = _cases(rec)
    dt = rec["settings"]["dt_s"]
    out = ["| method | tracks start | pos RMSE (m) | GOSPA (m) | % loc. / missed / false | tracks / target "
           "| false tracks / run | first track after birth (s) | track loss prob. | fragm. / run | s / run |",
           "|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|"]
    for name, m in case["methods"].items():
        out.append(row([name, m["initiation"], fixed(m["rmse_pos_m"], 1), pm(m["gospa_m"], m["gospa_se_m"]),
                        _shares(m), fixed(m["confirmed_tracks_per_target"], 2), fixed(m["false_tracks_per_run"], 2),
                        fixed(m["scans_to_first_track"] * dt, 2), fixed(m["track_loss_probability"], 3),
                        fixed(m["fragmentations_per_run"], 2), fixed(m["seconds_per_run"], 2)]))
    return out


# ---------------------------------------------------------------- SMC-PHD with GTDA labelling (Daniyan et al.)

SMCPHD = "evaluate/results/daniyan_smcphd/results.json"
_SMCPHD_ROWS = {"smcphd": "SMC-PHD estimates (unlabelled)",
                "known_association_kf": "Kalman filter per aircraft on its own detections, births known",
                "smcphd_gtda": "SMC-PHD + GTDA", "smcphd_hungarian": "SMC-PHD + Hungarian"}


def daniyan_smcphd(rec: dict) -> list[str]:
    """Every case and row of the SMC-PHD study: OSPA and GOSPA ± s.e., cardinality error, pooled RMS
    range and range-rate; label figures for the labelled rows, GTDA's repairs for its own."""
    out = ["| case | method | OSPA m (± s.e.) | GOSPA m (± s.e.) | abs. card. error | RMS range m | RMS range-rate m/s "
           "| switches / run | fragmentations / run | labels / run | GTDA repairs / run |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for _, case in _cases(rec):
        for key, label in _SMCPHD_ROWS.items():
            m = case["methods"][key]
            labelled = m.get("labels_per_run") is not None
            labels = [fixed(m[k], 1) for k in ("label_switches_per_run", "fragmentations_per_run", "labels_per_run")] \
                if labelled else ["-"] * 3
            repairs = m.get("conflicts_repaired_per_run")
            out.append(row([case["title"], label, pm(m["ospa_m"], m["ospa_se_m"], 0), pm(m["gospa_m"], m["gospa_se_m"], 0),
                            fixed(m["cardinality_mean_abs_error"], 2), fixed(m["rmse_pos_pooled_m"], 1),
                            fixed(m["rmse_vel_pooled_mps"], 2)] + labels + ["-" if repairs is None else fixed(repairs, 1)]))
    return out


# ---------------------------------------------------------------- FM front end (Daniyan et al., Section II)

FM = "evaluate/results/fm_front_end/results.json"


def fm_front_end(rec: dict) -> list[str]:
    """What the FM chain measured on the signals case: Pd, false alarms, detection errors against
    their reported deviations, cancellation depth, seconds per CPI."""
    f = rec["cases"]["signals"]["front_end"]
    per_target = " / ".join(fixed(p, 2) for p in f["pd_measured_per_target"])
    return ["| Pd (per target) | false alarms per map and pair (nominal Pfa x cells) | range RMSE of detections / "
            "their reported sd | Doppler RMSE / reported sd | cancellation depth | chain s / CPI |",
            "|---|---|---|---|---|---|",
            row([f"{f['pd_measured']:.3f} ({per_target})",
                 f"{f['false_alarms_per_map']:.2f} ({f['nominal_false_alarms_per_map']:.2f})",
                 f"{f['rmse_range_m']:.0f} m / {f['reported_sd_range_m']:.0f} m",
                 f"{f['rmse_doppler_hz']:.3f} Hz / {f['reported_sd_doppler_hz']:.3f} Hz",
                 f"{f['cancellation_depth_db']:.1f} dB",
                 f"{f['processing_seconds_per_cpi']:.2f} ({f['faster_than_real_time']:.0f}x real time)"])]


def fm_range_by_kind(rec: dict) -> list[str]:
    """The chain's range errors by kind of detection (clear, edge, crowded)."""
    kinds = rec["cases"]["signals"]["front_end"]["range_by_kind"]
    out = ["| kind | detections | range RMSE / reported sd |", "|---|---|---|"]
    for kind in ("clear", "edge", "crowded"):
        k = kinds[kind]
        out.append(row([kind, f"{k['detections']:,}", f"{k['rmse_range_m']:.0f} m / {k['reported_sd_range_m']:.0f} m "
                        f"({k['rmse_range_m'] / k['reported_sd_range_m']:.2f}x)"]))
    return out


_FM_ROWS = {"S-MSJPDA": "S-MSJPDA", "PMHT": "PMHT, marginal E-step (a smoother)",
            "true assignment": "true assignment (UKF on each target's labelled detections)"}


def fm_tracking(rec: dict) -> list[str]:
    """The trackers on the chain's detections beside the same trackers on model detections."""
    out = ["| method | signal-chain detections | model detections |", "|---|---|---|"]
    for name, label in _FM_ROWS.items():
        cells = [label]
        for case in ("signals", "model"):
            m = rec["cases"][case]["methods"][name]
            cells.append(f"{m['rmse_pos_m']:.1f} m, {m['rmse_vel_mps']:.2f} m/s, ANEES {m['anees']:.2f}, "
                         f"OSPA {m['ospa_m']:.1f}")
        out.append(row(cells))
    return out


def _mean(xs: list[float]) -> float:
    return sum(xs) / len(xs)


def jeit_pmht_per_target(rec: dict) -> list[str]:
    """The JEIT study's velocity RMSE and NEES (ANEES x 6, the paper's convention) per target beside
    the paper's Tables 2 and 4, and their means over the targets."""
    (_, case), = _cases(rec)
    paper = json.loads(PAPER_TABLES.read_text())["jeit2021_pmht3d"]
    vel = paper["table2_velocity_rmse_mps"]
    m3d, pmht, smoother = (case["methods"][n] for n in ("PMHT-3D", "PMHT", "UKF smoother (true assignment)"))
    columns = [(m3d["rmse_vel_per_target_mps"], 2), (vel["proposed"], 2), (pmht["rmse_vel_per_target_mps"], 2),
               (vel["PMHT"], 2), (smoother["rmse_vel_per_target_mps"], 2),
               ([6 * a for a in m3d["anees_per_target"]], 1), ([6 * a for a in smoother["anees_per_target"]], 1),
               (paper["table4_anees"], 2)]
    out = ["| target | PMHT-3D | paper: proposed | PMHT (labels given) | paper: PMHT | true-assignment smoother "
           "| NEES PMHT-3D | NEES true-assignment smoother | paper: NEES proposed |",
           "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for i in range(len(vel["proposed"])):
        out.append(row([str(i + 1)] + [fixed(xs[i], d) for xs, d in columns]))
    out.append(row(["mean"] + [fixed(_mean(xs), d) for xs, d in columns]))
    return out


BURN_IN_SEED1 = "evaluate/results/dense_crossing_burn_in_seed1/results.json"


def dense_crossing_burn_in(rec: dict) -> list[str]:
    """S-MSJPDA on dense_crossing's draws of another seed without the innovation bias test and with
    it at each burn-in: GOSPA ± s.e. and the median run (the default's row in bold)."""
    (_, case), = _cases(rec)
    out = [f"| S-MSJPDA on dense_crossing, seed {rec['seed']}'s {rec['mc_runs']} runs | GOSPA (m) ± s.e. | median run (m) |",
           "|---|---:|---:|"]
    for name, m in case["methods"].items():
        gospa = pm(m["gospa_m"], m["gospa_se_m"])
        if "default" in name:
            name, gospa = f"**{name}**", f"**{gospa}**"
        out.append(row(["no bias test" if name == "S-MSJPDA" else name, gospa, fixed(m["gospa_median_run_m"], 1)]))
    return out
