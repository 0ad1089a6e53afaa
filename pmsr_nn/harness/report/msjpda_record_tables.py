"""The tables of evaluate/RESULTS.md written from the records of the S-MSJPDA / P-MSJPDA study
(Lyu & Wang, IEEE Access 2019; evaluate/results/access2019_msjpda*/results.json): its three cases,
the m ablation, the sweeps over Pd and clutter beside the paper's run times, and S-MSJPDA starting
its own tracks from range and Doppler. One function per table, of the loaded record, returning its
lines; :mod:`.record_tables` places them."""

from __future__ import annotations

import json

from .bench_record_tables import PAPER_TABLES
from .record_cells import fixed, pm, row


def _cases(rec: dict) -> list[tuple[str, dict]]:
    return list(rec["cases"].items())


def _shares(m: dict) -> str:
    return " / ".join(f"{100 * m[f'gospa_{k}_share']:.0f}" for k in ("localisation", "missed", "false"))


MSJPDA = "evaluate/results/access2019_msjpda/results.json"
_MSJPDA_CASES = {"nominal": "nominal (2 km apart)", "close_500m": "500 m apart",
                 "loose_prior": "initiation 500 m / 20 m/s"}
_MSJPDA_ROWS = {"S-MSJPDA": "S-MSJPDA", "P-MSJPDA": "P-MSJPDA (m = 10)",
                "P-MSJPDA relaxation": "P-MSJPDA (m = 10, relaxation)", "P-MSJPDA m=100": "P-MSJPDA (m = 100)",
                "true assignment": "true assignment"}


def access2019_msjpda(rec: dict) -> list[str]:
    """The three cases of the MSJPDA study: RMSE after the warm-up (over every scan in brackets),
    over the true-assignment reference, ANEES, loss and swap probabilities, P-MSJPDA's largest
    duality gap, seconds per run."""
    out = ["| case | method | pos RMSE (m) | / reference | ANEES | loss prob. | swap prob. | max gap | s / run |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for key, case in _cases(rec):
        reference = case["methods"]["true assignment"]["rmse_pos_m"]
        for i, (name, label) in enumerate(_MSJPDA_ROWS.items()):
            m = case["methods"][name]
            gap = m.get("max_duality_gap")
            out.append(row([_MSJPDA_CASES[key] if i == 0 else "", label,
                            f"{m['rmse_pos_m']:.1f} ({m['rmse_pos_all_scans_m']:.1f})", fixed(m["rmse_pos_m"] / reference, 2),
                            fixed(m["anees"], 2), fixed(m["loss_probability"], 3), fixed(m["swap_probability"], 3),
                            "" if gap is None else fixed(gap, 1), fixed(m["seconds_per_run"], 3)]))
    return out


MSJPDA_MBEST = "evaluate/results/access2019_msjpda_mbest/results.json"


def access2019_msjpda_mbest(rec: dict) -> list[str]:
    """The m ablation: each row's RMSE, over the true assignment's, ANEES, swap probability,
    P-MSJPDA's largest duality gap, seconds per run and over S-MSJPDA m=10's, per Pd."""
    out = ["| Pd | method | pos RMSE (m) | / reference | ANEES | swap prob. | max gap | s / run | time / S-MSJPDA m=10 |",
           "|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for _, case in _cases(rec):
        methods = case["methods"]
        reference = methods["true assignment"]["rmse_pos_m"]
        base = methods["S-MSJPDA m=10"]["seconds_per_run"]
        for i, (name, m) in enumerate(methods.items()):
            gap = m.get("max_duality_gap")
            out.append(row([f"{case['pd']:g}" if i == 0 else "", name, fixed(m["rmse_pos_m"], 1),
                            fixed(m["rmse_pos_m"] / reference, 2), fixed(m["anees"], 2), fixed(m["swap_probability"], 3),
                            "" if gap is None else fixed(gap, 1), fixed(m["seconds_per_run"], 3),
                            fixed(m["seconds_per_run"] / base, 1)]))
    return out


MSJPDA_PD = "evaluate/results/access2019_msjpda_pd/results.json"
MSJPDA_CLUTTER = "evaluate/results/access2019_msjpda_clutter/results.json"


def _msjpda_sweep(rec: dict, key: str, header: str, timing: str) -> list[str]:
    """A sweep of the MSJPDA study over ``key`` (a case field): RMSE of each row, over the true
    assignment's, loss probabilities, seconds per run and their ratios, beside the paper's times
    (``timing``: the paper's table in evaluate/reference/paper_tables.json)."""
    paper = json.loads(PAPER_TABLES.read_text())["access2019_msjpda"][timing]
    out = [f"| {header} | S-MSJPDA | P-MSJPDA (m = 10) | P-MSJPDA (m = 100) | true assignment | S / ref | P m=100 / ref "
           "| loss S / P / P100 | s/run S / P / P100 | P/S, P100/S time | paper s/run S / P | paper P/S |",
           "|---:|---:|---:|---:|---:|---:|---:|---|---|---|---|---:|"]
    for _, case in _cases(rec):
        s, p, p100, ref = (case["methods"][n] for n in ("S-MSJPDA", "P-MSJPDA", "P-MSJPDA m=100", "true assignment"))
        level = f"{case[key]:g}"
        ps, pp = paper["S-MSJPDA"][level], paper["P-MSJPDA"][level]
        out.append(row([level] + [fixed(m["rmse_pos_m"], 1) for m in (s, p, p100, ref)]
                       + [fixed(s["rmse_pos_m"] / ref["rmse_pos_m"], 2), fixed(p100["rmse_pos_m"] / ref["rmse_pos_m"], 2),
                          " / ".join(fixed(m["loss_probability"], 3) for m in (s, p, p100)),
                          f"{s['seconds_per_run']:.3f} / {p['seconds_per_run']:.3f} / {p100['seconds_per_run']:.2f}",
                          f"{p['seconds_per_run'] / s['seconds_per_run']:.1f}, {p100['seconds_per_run'] / s['seconds_per_run']:.1f}",
                          f"{ps} / {pp}", fixed(pp / ps, 1)]))
    return out


def access2019_msjpda_pd(rec: dict) -> list[str]:
    """The sweep over Pd (50 clutter points), the paper's Table 1 times beside ours."""
    return _msjpda_sweep(rec, "pd", "Pd", "table1_runtime_s_vs_pd_50_clutter")


def access2019_msjpda_clutter(rec: dict) -> list[str]:
    """The sweep over clutter points per scan (Pd 0.8), the paper's Table 2 times beside ours."""
    return _msjpda_sweep(rec, "clutter_per_scan", "clutter / scan", "table2_runtime_s_vs_clutter_pd_0.8")


MSJPDA_INITIATION = "evaluate/results/access2019_msjpda_initiation/results.json"


def _short_time(x: float) -> str:
    """A time as the initiation table writes it: 2 decimals below 1 (0 as 0.0), else 1."""
    return fixed(x, 2 if 0 < x < 1 else 1)


def access2019_msjpda_initiation(rec: dict) -> list[str]:
    """Each row (S-MSJPDA handed its tracks; S-MSJPDA and BP starting them from range and Doppler)
    per case: GOSPA, its shares, tracks, false tracks, missed targets, first track after birth,
    seconds per run."""
    dt = rec["settings"]["dt_s"]
    out = ["| case | row | tracks start | GOSPA (m) ± s.e. | % loc. / missed / false | tracks / target "
           "| false tracks / run | missed-target fraction | first track (s) | s / run |",
           "|---|---|---|---:|---|---:|---:|---:|---:|---:|"]
    for key, case in _cases(rec):
        for name, m in case["methods"].items():
            out.append(row([_MSJPDA_CASES[key].replace("initiation 500 m / 20 m/s", "loose prior"), name,
                            "detections" if m["initiation"] == "detections" else "oracle",
                            pm(m["gospa_m"], m["gospa_se_m"]), _shares(m), fixed(m["confirmed_tracks_per_target"], 2),
                            fixed(m["false_tracks_per_run"], 2), fixed(m["missed_target_fraction"], 2),
                            _short_time(m["scans_to_first_track"] * dt), _short_time(m["seconds_per_run"])]))
    return out
