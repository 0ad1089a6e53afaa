"""The tables of README.md and evaluate/RESULTS.md written from the records of the MDFNN paper's
studies (FITEE 2023): the classical baselines against the PCRB, the three-trajectory study and its
learned rows, and the ablations (Tables 3, 4, 5, 7). One function per table, of the loaded
record, returning its lines; :mod:`.record_tables` places them between the documents' markers.
Row labels are the document's choice and sit here; every number is the record's or, in a
*paper* column, the paper's (``evaluate/reference/paper_tables.json``)."""

from __future__ import annotations

import json
import statistics
from pathlib import Path

from .record_cells import fixed, row, significant

ROOT = Path(__file__).resolve().parents[3]
PAPER_TABLES = "evaluate/reference/paper_tables.json"
"""The paper's tables, the *paper* columns beside ours (read from the repository, not from the
record's absolute path)."""


def _paper(record_ref: dict) -> dict:
    """The paper's table the record names (``reference.table``: ``file_key.table_key``), from the
    repository's copy of the reference file."""
    book, table = record_ref["table"].split(".", 1)
    return json.loads((ROOT / PAPER_TABLES).read_text())[book][table]


# ---------------------------------------------------------------- the three-trajectory study

THREE = "evaluate/results/fitee2023_three_trajectories/results.json"


def _cases(rec: dict) -> list[tuple[str, dict]]:
    return list(rec["cases"].items())


def _ms_per_run(rec: dict, method: str) -> float:
    """Median over the cases of the method's ``seconds_per_run``, in ms."""
    return 1e3 * statistics.median(case["methods"][method]["seconds_per_run"] for _, case in _cases(rec))


def _diverged_cell(value: str, m: dict, first: bool) -> str:
    if not m.get("diverged_runs"):
        return value
    if first:
        return (f"{value} ({m['diverged_runs']} of {m['runs']} runs diverged; median run "
                f"{m['median_run_rmse_pos_m']:.1f})")
    return f"{value} ({m['diverged_runs']} diverged; median {m['median_run_rmse_pos_m']:.1f})"


def readme_three_trajectories(rec: dict) -> list[str]:
    """README's main table: RMSE per trajectory (``*`` below the per-trajectory PCRB), the paper's
    Table 6 beside it, seed groups as the mean of their seeds, the PCRB and its q = 0 floor."""
    paper = _paper(rec["reference"])
    cases = _cases(rec)
    out = ["| method | traj. 1 | paper | traj. 2 | paper | traj. 3 | paper |",
           "|---|---:|---:|---:|---:|---:|---:|"]
    singles = [("EKF", "EKF"), ("UKF", "UKF"), ("SI+KF", "SI+KF"), ("particle filter, 5000 particles", "PF"),
               ("DFNN", "DFNN"), ("MDFNN", "MDFNN"), ("RNN", "RNN")]
    for label, name in singles:
        cells, first = [label], True
        for cname, case in cases:
            m = case["methods"][name]
            value = fixed(m["rmse_pos_m"], 2) + ("*" if m.get("below_bound") else "")
            cells.append(_diverged_cell(value, m, first))
            first = first and not m.get("diverged_runs")
            p = paper.get(cname, {}).get(name)
            cells.append("-" if p is None else f"{p:.2f}")
        out.append(row(cells))
    groups = [("MDFNN local/residual (compact), mean of 3 seeds", "MDFNN local"),
              ("KalmanNet-style, mean of 3 seeds", "KalmanNet"),
              ("KalmanNet-style trained on 300-scan windows, whole sequence, mean of 3 seeds",
               "KalmanNet 300-scan training, whole sequence")]
    for label, group in groups:
        cells = [label]
        for _, case in cases:
            g = case["seed_groups"][group]
            assert g["seeds"] == 3, (group, g["seeds"])
            cells += [fixed(g["rmse_pos_m"]["mean"], 2), "-"]
        out.append(row(cells))
    for label, key in (("PCRB, filtering, per trajectory", "pos_m"),
                       ("PCRB with q = 0 (the floor for flights without process noise)", "q0_pos_m")):
        cells = [label]
        for _, case in cases:
            cells += [fixed(case["pcrb"][key], 2), ""]
        out.append(row(cells))
    return out


def results_three_trajectories(rec: dict) -> list[str]:
    """evaluate/RESULTS.md's Table 6 analogue: RMSE per trajectory beside the paper's, RMSE over the
    own PCRB per trajectory and ms per run (median over the trajectories)."""
    paper = _paper(rec["reference"])
    cases = _cases(rec)
    out = ["| method | traj. 1 | paper | traj. 2 | paper | traj. 3 | paper | RMSE / own PCRB | ms per run |",
           "|---|---:|---:|---:|---:|---:|---:|---|---:|"]
    two_decimals, one_decimal = (lambda x: fixed(x, 2)), (lambda x: fixed(x, 1))
    rows = [("EKF", "EKF", two_decimals), ("UKF", "UKF", two_decimals),
            ("SI+KF (plain SI fixes)", "SI+KF", one_decimal),
            ("PF, 5000 particles, roughening 0.2", "PF", lambda x: significant(x, 2)),
            ("DFNN", "DFNN", one_decimal), ("MDFNN", "MDFNN", one_decimal), ("RNN", "RNN", one_decimal)]
    for label, name, ratio in rows:
        cells = [label]
        for cname, case in cases:
            p = paper.get(cname, {}).get(name)
            cells += [fixed(case["methods"][name]["rmse_pos_m"], 2), "" if p is None else f"{p:.2f}"]
        cells.append(" / ".join(ratio(case["methods"][name]["over_bound"]) for _, case in cases))
        cells.append(fixed(_ms_per_run(rec, name), 1))
        out.append(row(cells))
    for label, key in (("PCRB filtering, per trajectory", "pos_m"), ("PCRB with q = 0 (floor)", "q0_pos_m")):
        cells = [label]
        for _, case in cases:
            cells += [fixed(case["pcrb"][key], 2), ""]
        out.append(row(cells + ["", ""]))
    return out


def _group_cell(case: dict, group: str, bold: bool = False) -> str:
    """``mean (min-max)`` of a seed group's RMSE, the mean in bold if asked."""
    r = case["seed_groups"][group]["rmse_pos_m"]
    mean = f"**{r['mean']:.2f}**" if bold else f"{r['mean']:.2f}"
    return f"{mean} ({r['min']:.2f}-{r['max']:.2f})"


def results_learned_rows(rec: dict) -> list[str]:
    """evaluate/RESULTS.md's issue-17 table: the learned rows (seed groups: mean (min-max)) beside the
    EKF, over the filtering PCRB and over their finite-memory bound."""
    cases = [c for _, c in _cases(rec)]
    out = ["| method | traj. 1 | traj. 2 | traj. 3 | / filtering PCRB | scans read | / finite-memory bound |",
           "|---|---:|---:|---:|---|---:|---|"]
    ekf = [c["methods"]["EKF"] for c in cases]
    out.append(row(["EKF (matched model)"] + [fixed(m["rmse_pos_m"], 2) for m in ekf]
                   + [" / ".join(fixed(m["over_bound"], 2) for m in ekf), "all", ""]))
    for label, group, bold in (("**KalmanNet-style**, 3 seeds", "KalmanNet", True),
                               ("MDFNN local/residual (compact), 3 seeds", "MDFNN local", False)):
        gs = [c["seed_groups"][group] for c in cases]
        assert all(g["seeds"] == 3 for g in gs), group
        ratio = " / ".join(fixed(g["over_bound"]["mean"], 2) for g in gs)
        scans = {c["methods"][m]["memory_scans"] for c in cases for m in c["seed_groups"][group]["methods"]}
        assert len(scans) == 1, (group, scans)
        out.append(row([label] + [_group_cell(c, group, bold) for c in cases]
                       + [f"**{ratio}**" if bold else ratio, str(scans.pop()),
                          " / ".join(fixed(g["over_memory_bound"]["mean"], 2) for g in gs)]))
    for label, name, memory_decimals in (("MDFNN, paper-literal (released)", "MDFNN", 2),
                                         ("RNN, paper-literal (released)", "RNN", 1)):
        ms = [c["methods"][name] for c in cases]
        assert len({m["memory_scans"] for m in ms}) == 1, name
        out.append(row([label] + [fixed(m["rmse_pos_m"], 2) for m in ms]
                       + [" / ".join(fixed(m["over_bound"], 1) for m in ms), str(ms[0]["memory_scans"]),
                          " / ".join(fixed(m["over_memory_bound"], memory_decimals) for m in ms)]))
    out.append(row(["PCRB filtering, per trajectory"] + [fixed(c["pcrb"]["pos_m"], 2) for c in cases] + ["", "", ""]))
    return out


def _paired(case: dict, group: str) -> str:
    (c,) = [c for c in case["comparisons"] if c["learned"] == group]
    return f"{c['margin_m']:.2f} +- {c['se_m']:.2f}"


def results_whole_sequence(rec: dict) -> list[str]:
    """evaluate/RESULTS.md's whole-sequence table: the three KalmanNet-style seed groups, RMSE mean
    (min-max), over the PCRB, paired against the best classical row, seconds per run (the seeds'
    medians over the trajectories, min-max)."""
    cases = [c for _, c in _cases(rec)]
    out = ["| KalmanNet-style, 3 seeds | traj. 1 | traj. 2 | traj. 3 | / filtering PCRB "
           "| paired against the best classical (m) | s / run |",
           "|---|---:|---:|---:|---|---|---:|"]
    for label, group, bold in (("100-scan training, 100-scan windows (stride 50)", "KalmanNet", False),
                               ("100-scan training, whole sequence", "KalmanNet, whole sequence", False),
                               ("**300-scan training, whole sequence**", "KalmanNet 300-scan training, whole sequence",
                                True)):
        gs = [c["seed_groups"][group] for c in cases]
        assert all(g["seeds"] == 3 for g in gs), group
        ratio = " / ".join(fixed(g["over_bound"]["mean"], 2) for g in gs)
        seconds = [statistics.median(c["methods"][m]["seconds_per_run"] for c in cases) for m in gs[0]["methods"]]
        out.append(row([label] + [_group_cell(c, group, bold) for c in cases]
                       + [f"**{ratio}**" if bold else ratio, " / ".join(_paired(c, group) for c in cases),
                          f"{min(seconds):.3f}-{max(seconds):.3f}"]))
    out.append(row(["PCRB, filtering, per trajectory"] + [fixed(c["pcrb"]["pos_m"], 2) for c in cases] + ["", "", ""]))
    return out


# ---------------------------------------------------------------- ablations (the MDFNN paper's Tables 3, 4, 5, 7)

DFNN_VS_MDFNN = "evaluate/results/ablation_dfnn_vs_mdfnn/results.json"
SEQUENCE_SIZE = "evaluate/results/ablation_sequence_size/results.json"
FILTER_ORDER = "evaluate/results/ablation_filter_order/results.json"
ALTITUDE = "evaluate/results/ablation_altitude/results.json"
_TRAJECTORIES = ("trajectory_1", "trajectory_2", "trajectory_3")


def _paper_table(key: str) -> dict:
    return json.loads((ROOT / PAPER_TABLES).read_text())["fitee2023_mdfnn"][key]


def _per_trajectory_and_paper(rec: dict, paper_key: str, header: list[str]) -> list[str]:
    """An ablation's rows: its label, the RMSE per trajectory and the paper's one figure for the label."""
    paper = _paper_table(paper_key)
    out = list(header)
    for r in rec["rows"]:
        out.append(row([r["label"]] + [fixed(r["rmse_pos_m"][t], 2) for t in _TRAJECTORIES]
                       + [fixed(paper[r["label"]], 2)]))
    return out


def ablation_dfnn_vs_mdfnn(rec: dict) -> list[str]:
    """Table 3: DFNN and MDFNN at the same budget, RMSE per trajectory, the paper's beside."""
    return _per_trajectory_and_paper(rec, "table3_ablation_rmse_pos_m", [
        "| network | traj. 1 | traj. 2 | traj. 3 | paper (its own test data) |", "|---|---:|---:|---:|---:|"])


def ablation_sequence_size(rec: dict) -> list[str]:
    """Table 4: the sequence size epsilon, RMSE per trajectory, the paper's one-trajectory column."""
    return _per_trajectory_and_paper(rec, "table4_sequence_size_rmse_pos_m", [
        "| epsilon | traj. 1 | traj. 2 | traj. 3 | paper |", "|---:|---:|---:|---:|---:|"])


def ablation_filter_order(rec: dict) -> list[str]:
    """Table 5: the filter order M, RMSE per trajectory beside the paper's."""
    paper = _paper_table("table5_filter_order_rmse_pos_m")
    out = ["| M | traj. 1 | paper | traj. 2 | paper | traj. 3 | paper |", "|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rec["rows"]:
        cells = [r["label"]]
        for t in _TRAJECTORIES:
            cells += [fixed(r["rmse_pos_m"][t], 2), fixed(paper[t][r["label"]], 2)]
        out.append(row(cells))
    return out


def ablation_altitude(rec: dict) -> list[str]:
    """Table 7: the planar EKF on targets at altitude h: RMSE, its increase over h = 0, ANEES, the
    paper's RMSE."""
    paper = _paper_table("table7_altitude_ekf_rmse_pos_m")
    out = ["| h (m) | RMSE (m) | RMSE - RMSE_0 (m) | increase | ANEES | paper RMSE |", "|---:|---:|---:|---:|---:|---:|"]
    for case in rec["cases"].values():
        (m,) = case["methods"].values()
        h = f"{m['altitude_m']:.0f}"
        increase = m["relative_increase_pct"]
        out.append(row([h, fixed(m["rmse_pos_m"], 2), fixed(m["abs_diff_rmse0_m"], 2),
                        f"{fixed(increase, 2 if 0 < increase < 1 else 1)} %",
                        fixed(m["anees"], 2), fixed(paper[h], 2)]))
    return out


# ---------------------------------------------------------------- classical baselines against the PCRB

BASELINES = "evaluate/results/baselines_vs_bounds/results.json"
_BASELINE_LABELS = {"UKF + URTS": "UKF + unscented RTS", "SI+GN+KF": "SI (2 Gauss-Newton steps) + KF",
                    "PF 20000 rough.": "bootstrap PF, 20,000 particles, roughening 0.2"}


def _baselines(rec: dict, variant: str) -> list[str]:
    """One variant's filters, smoothers and bounds: RMSE, MSE over each track's own bound, seconds."""
    (res,) = [r for r in rec["results"] if r["variant"] == variant]
    out = ["| method | pos RMSE (m) | vel RMSE (m/s) | MSE / own bound | time (s) |", "|---|---:|---:|---:|---:|"]
    for r in res["rows"]:
        label = _BASELINE_LABELS.get(r["method"], r["method"]).replace(" (filtering)", ", filtering") \
            .replace(" (smoothing)", ", smoothing")
        if r["kind"] == "bound":
            out.append(row([label, fixed(r["position_rmse_m"], 2), fixed(r["velocity_rmse_mps"], 3), "", ""]))
            continue
        ratio, decimals = r["mse_over_per_track_bound"], 2 if r["mse_over_per_track_bound"] < 10 else 1
        out.append(row([label, fixed(r["position_rmse_m"], 2), fixed(r["velocity_rmse_mps"], 3),
                        f"{fixed(ratio, decimals)} +- {fixed(r['mse_over_per_track_bound_se'], decimals)}",
                        fixed(r["seconds"], 2 if r["seconds"] < 10 else 0)]))
    return out


def baselines_envelope(rec: dict) -> list[str]:
    return _baselines(rec, "envelope")


def baselines_literal(rec: dict) -> list[str]:
    return _baselines(rec, "literal")


LEARNED_BOUNDS = "evaluate/results/learned_vs_bounds/results.json"


def learned_vs_bounds(rec: dict) -> list[str]:
    """The test split's learned and classical rows against the filtering / smoothing PCRB and the
    learned rows' finite-memory bound."""
    out = ["| method | causal | pos RMSE (m) | vel RMSE (m/s) | / own PCRB | MSE / own PCRB per track | scans read "
           "| finite-memory bound (m) | / finite-memory bound |",
           "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rec["rows"]:
        memory = [str(r["memory_scans"]), fixed(r["memory_bound_position_m"], 2), fixed(r["over_memory_bound"], 2)] \
            if "memory_scans" in r else ["all", "-", "-"]
        out.append(row([r["method"], "yes" if r["causal"] else "no", fixed(r["position_rmse_m"], 2),
                        fixed(r["velocity_rmse_mps"], 3), fixed(r["over_bound"], 2),
                        f"{r['mse_over_bound']:.2f} +- {r['mse_over_bound_se']:.2f}"] + memory))
    filtering, smoothing = rec["bounds"]["filtering"], rec["bounds"]["smoothing"]
    out.append(row(["PCRB filtering (per trajectory)", "", fixed(filtering["position_m"], 2),
                    fixed(filtering["velocity_mps"], 3), "1.00", "", "all", "", ""]))  # the bound over itself
    out.append(row(["PCRB smoothing (per trajectory)", "", fixed(smoothing["position_m"], 2),
                    fixed(smoothing["velocity_mps"], 3), "", "", "all", "", ""]))
    return out


MISMATCH = "evaluate/results/fitee2023_mismatch/results.json"


def mismatch_whole_sequence(rec: dict) -> list[str]:
    """The KalmanNet-style filter's 100-scan windows against whole-sequence inference on the three
    mismatched flights: mean (min-max) over the three seeds, and paired against the tuned IMM."""
    out = ["| KalmanNet, 3 seeds | patrol | speed changes | weave | paired against the tuned IMM (m): patrol / speed / weave |",
           "|---|---:|---:|---:|---|"]
    for label, group in (("100-scan windows, stride 50 (as above)", "KalmanNet"), ("whole sequence", "KalmanNet, whole sequence")):
        cells, paired = [], []
        for case in rec["cases"].values():
            r = case["seed_groups"][group]["rmse_pos_m"]
            cells.append(f"{r['mean']:.2f} ({r['min']:.2f}-{r['max']:.2f})")
            (c,) = [c for c in case["comparisons"] if c["learned"] == group and c["classical"] == "IMM (tuned)"]
            paired.append(f"{c['margin_m']:.2f} +- {c['se_m']:.2f}")
        out.append(row([label, *cells, " / ".join(paired)]))
    return out


MISMATCH_FIRST = "evaluate/results/history/fitee2023_mismatch_40cd609.json"
"""The mismatch study's first record (2026-11-23, the KalmanNet rows before the restart of a lost
filter), as git held it at 40cd609."""


def mismatch(rec: dict, first: dict) -> list[str]:
    """Position RMSE per flight of the classical filters, the learned trackers' three seeds (mean,
    min-max; the KalmanNet rows before and after the restart) and the PCRB, with seed 0's or the
    filter's median run; the lowest tracker per flight in bold."""
    cases = list(rec["cases"].values())

    def m(c: dict, name: str) -> dict:
        return c["methods"][name]

    def group(r: dict, name: str) -> list[str]:
        return [f"{g['mean']:.2f} ({g['min']:.1f}-{g['max']:.1f})"
                for g in (c["seed_groups"][name]["rmse_pos_m"] for c in r["cases"].values())]

    def medians(r: dict, name: str) -> str:
        return " / ".join(fixed(c["methods"][name]["median_run_rmse_pos_m"], 1) for c in r["cases"].values())

    tuned = [m(c, "EKF (tuned q)")["rmse_pos_m"] for c in cases]
    if [round(x, 2) for x in tuned] != [round(m(c, "UKF (tuned q)")["rmse_pos_m"], 2) for c in cases]:
        raise ValueError("the mismatch table's 'EKF / UKF (tuned q = 1)' row needs the two equal to 2 decimals")
    means = {"EKF (tuned q)": tuned, "IMM (tuned)": [m(c, "IMM (tuned)")["rmse_pos_m"] for c in cases]}
    means.update({g: [c["seed_groups"][g]["rmse_pos_m"]["mean"] for c in cases] for g in ("MDFNN local", "KalmanNet")})
    best = [min(v[i] for v in means.values()) for i in range(len(cases))]

    def cells(values: list[float]) -> list[str]:
        return [f"**{x:.2f}**" if x == b else f"{x:.2f}" for x, b in zip(values, best)]

    return ["| method | patrol | speed changes | weave | median run (patrol / speed / weave) |",
            "|---|---:|---:|---:|---|",
            row(["EKF (recipe q = 1e-7)", *[fixed(m(c, "EKF")["rmse_pos_m"], 2) for c in cases], ""]),
            row(["EKF / UKF (tuned q = 1)", *cells(tuned), medians(rec, "EKF (tuned q)")]),
            row(["IMM (tuned: q 1e-9 / 0.3, stay 0.9999)", *cells(means["IMM (tuned)"]), medians(rec, "IMM (tuned)")]),
            row(["MDFNN local, 3 seeds", *group(rec, "MDFNN local"), medians(rec, "MDFNN local [seed 0]") + " (seed 0)"]),
            row(["KalmanNet (robust: gain x 0.1, innovations clipped at 5 sd), 3 seeds, before the restart (2026-11-23)",
                 *group(first, "KalmanNet"), medians(first, "KalmanNet [seed 0]") + " (seed 0)"]),
            row(["KalmanNet, the same checkpoints with the restart of a lost filter (2026-11-26)",
                 *group(rec, "KalmanNet"), medians(rec, "KalmanNet [seed 0]") + " (seed 0)"]),
            row(["PCRB filtering, per flight", *[fixed(c["pcrb"]["pos_m"], 2) for c in cases], ""])]
