"""Typed results (:mod:`pmsr_nn.harness.results.typed`): the kind read or inferred in one place, typed rows,
one-line refusals; the report's flags and cells with their Monte Carlo error."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

from pmsr_nn.errors import ConfigError
from pmsr_nn.harness.report.flags import flag_paragraphs, warning_lines
from pmsr_nn.harness.report.method_tables import summary_table
from pmsr_nn.harness.report.multitarget_tables import multi_target_tables
from pmsr_nn.harness.results.typed import Results

ROOT = Path(__file__).resolve().parents[1]


def designed_row(rmse=10.9, bound=12.34, ratio=0.80, se=0.05, below=True, floor=8.0, ratio0=1.9, se0=0.1,
                 below0=False) -> dict:
    return {"kind": "ekf", "causal": True, "initiation": "association known", "rmse_pos_m": rmse,
            "rmse_vel_mps": 0.2, "anees": 0.5, "seconds_per_run": 0.01, "rmse_pos_pooled_m": rmse + 0.1,
            "rmse_pos_all_scans_m": rmse + 1, "median_run_rmse_pos_m": rmse, "runs": 5, "diverged_runs": 0,
            "bound": "filtering", "bound_pos_m": bound, "over_bound": rmse / bound, "mse_over_bound": ratio,
            "mse_over_bound_se": se, "below_bound": below, "bound_q0_pos_m": floor, "mse_over_q0_bound": ratio0,
            "mse_over_q0_bound_se": se0, "below_q0_bound": below0}


def designed(**row) -> dict:
    """A designed scenario's results with one case and one EKF row (as ``finalise`` writes them;
    made-up values)."""
    pcrb = {"pos_m": 12.34, "vel_mps": 0.3, "smoothing_pos_m": 11.0, "smoothing_vel_mps": 0.2, "q0_pos_m": 8.0,
            "q0_smoothing_pos_m": 7.0}
    return {"scenario": "s", "seed": 0, "mc_runs": 5,
            "settings": {"dt_s": 1.0, "warmup_steps": 2, "block_runs": 5, "divergence_m": 1000.0,
                         "methods": {"EKF": {"kind": "ekf", "reads": "measurements"}}},
            "cases": {"c": {"title": "c", "steps": 4, "targets": ["t"], "methods": {"EKF": designed_row(**row)},
                            "pcrb": pcrb, "seed_groups": {}, "comparisons": [],
                            "curves": {"rmse_pos_m": {"EKF": [20.0, 15.0, 11.0, 10.0]}, "pcrb_pos_m": [20.0] * 4,
                                       "pcrb_smoothing_pos_m": [19.0] * 4, "pcrb_q0_pos_m": [9.0] * 4}}}}


def sampled() -> dict:
    """A multi-target study's results (``kind: multitarget`` written before the result kind), one
    tracker and the PCRB row; made-up values chosen to be told apart in the rendered text (no
    measured or paper figure)."""
    row = {"kind": "s_msjpda", "causal": True, "initiation": "detections", "rmse_pos_m": 52.0, "rmse_vel_mps": 3.0,
           "anees": None, "seconds_per_run": 1.5, "rmse_pos_pooled_m": 55.0, "rmse_pos_all_scans_m": 60.0,
           "runs": 4, "rmse_pos_per_target_m": [50.0, 54.0], "ospa_m": 120.0, "gospa_m": 150.0, "gospa_se_m": 13.25,
           "gospa_localisation_share": 0.5, "gospa_missed_share": 0.3, "gospa_false_share": 0.2,
           "cardinality_mean_abs_error": 0.25, "rmse_pos_assigned_per_target_m": [51.0, None],
           "label_switches_per_run": 0.5, "confirmed_tracks_per_target": 1.0, "false_tracks_per_run": 0.5,
           "missed_target_fraction": 0.1, "scans_to_first_track": 3.0, "track_loss_probability": 0.0,
           "fragmentations_per_run": 0.25}
    bound = {"kind": "pcrb", "causal": True, "initiation": "association known", "bound": "filtering", "q": "model",
             "rmse_pos_m": 20.0, "rmse_pos_all_scans_m": 25.0, "rmse_pos_per_target_m": [19.0, 21.0],
             "seconds_per_run": None, "bound_pos_m": 20.0, "over_bound": None, "below_bound": False, "runs": 4}
    return {"scenario": "mt", "kind": "multitarget", "seed": 1, "mc_runs": 4,
            "settings": {"scans": 10, "dt_s": 2.0, "methods": {"S-MSJPDA": {"kind": "s_msjpda", "reads": "detections"},
                                                                "PCRB": {"kind": "pcrb", "reads": "truth"}}},
            "cases": {"c": {"title": "two", "steps": 10, "targets": ["a", "b"], "pd": 0.9, "clutter_per_scan": 5.0,
                            "spacing_m": 500.0, "pcrb": None, "methods": {"S-MSJPDA": row, "PCRB": bound},
                            "curves": {"rmse_pos_m": {"S-MSJPDA": [[50.0] * 10] * 2, "PCRB": [[20.0] * 10] * 2}}}}}


def test_the_kind_is_read_and_inferred_for_older_files_in_one_place():
    res = designed()
    assert Results.from_dict(res).kind == "designed"  # no key: a PCRB in every case
    assert Results.from_dict({**res, "kind": "sampled"}).kind == "sampled"  # the key wins
    old = sampled()
    assert Results.from_dict(old).kind == "sampled"  # the older key named the retired schema, not the kind
    assert Results.from_dict({**old, "kind": "sampled"}).kind == "sampled"  # as finalise writes it now


def test_a_results_file_of_the_retired_multitarget_schema_still_renders(tmp_path):
    """evaluate/results/access2019_msjpda/results.json was written by a ``kind: multitarget`` study
    (its settings: a tracker section, converged_from_scan, no components): the report renders
    from it, its paragraph quoting that file's settings and its tables that file's figures."""
    import json

    import numpy as np
    from types import SimpleNamespace

    from pmsr_nn.harness.report.document import write_report

    res = json.loads((ROOT / "evaluate" / "results" / "access2019_msjpda" / "results.json").read_text())
    assert "tracker" in res["settings"] and "components" not in res["settings"]  # the retired schema's settings
    examples = {c: {"truth": np.zeros((v["steps"], len(v["targets"]), 2)) + np.arange(v["steps"])[:, None, None]}
                for c, v in res["cases"].items()}
    files = write_report(res, tmp_path, examples, SimpleNamespace(transmitters=[], receivers=[]), None, None)
    report = (tmp_path / "report.md").read_text()
    st = res["settings"]
    assert (f"{st['scans']} scans of {st['dt_s']} s, 2-D." in report
            and f"gate probability {st['tracker']['gate_probability']}," in report
            and f"Loss rule: {st['loss']['successive_scans']} scans dummy-most-probable" in report)
    row = res["cases"]["nominal"]["methods"]["S-MSJPDA"]
    assert f"| S-MSJPDA | {row['rmse_pos_m']:.2f} ± {row['rmse_pos_se_m']:.2f} |" in report
    assert {f.name for f in files} >= {"report.md", "nominal_rmse.png", "trajectories.png"}


def test_bad_results_are_refused_in_one_line():
    with pytest.raises(ConfigError, match="kind 'tracked' is none of designed, sampled"):
        Results.from_dict({**designed(), "kind": "tracked"})
    with pytest.raises(ConfigError, match="kind 'designed' but case 'c' has no PCRB"):
        Results.from_dict({**sampled(), "kind": "designed"})
    with pytest.raises(ConfigError, match="no 'cases' table"):
        Results.from_dict({"rows": []})
    old = designed()
    old["cases"]["c"]["curves"] = {"rmse_pos_m_per_target": []}
    with pytest.raises(ConfigError, match="case 'c' has no curves.rmse_pos_m: a results.json of an older layout"):
        Results.from_dict(old)


def test_rows_are_typed_with_their_optional_parts():
    r = Results.from_dict(sampled())
    case = r.cases["c"]
    tracker, bound = case.methods["S-MSJPDA"], case.methods["PCRB"]
    assert tracker.sets.gospa_se_m == 13.25 and tracker.tracks.fragmentations_per_run == 0.25
    assert tracker.bound is None and tracker.memory is None and tracker.space is None and tracker.tbd is None
    assert bound.sets is None and bound.tracks is None and bound.bound.which == "filtering" and not bound.below_bound
    assert case.study.pd == 0.9 and case.study.clutter_list == "sensor" and case.pcrb is None
    row = Results.from_dict(designed()).cases["c"].methods["EKF"]
    b = row.bound
    assert (b.mse_ratio, b.mse_ratio_se, b.below, b.below_q0) == (0.80, 0.05, True, False)


def test_a_flag_states_its_interval_and_its_distance_in_standard_errors():
    text = " ".join(flag_paragraphs(designed()))
    # (1 - 0.80) / 0.05 = 4.0 standard errors under 1
    assert ("EKF on c (MSE / bound^2 0.800 +- 0.050), 4.0 s.e. below 1: RMSE 10.90 m against the bound 12.34 m"
            in text)
    assert "no method is below it beyond its Monte Carlo error" in text
    (line,) = warning_lines(designed())
    assert line == "warning   EKF on c below its filtering bound: MSE / bound^2 0.80 ± 0.05, 4.0 s.e. below 1"


def test_the_floor_flag_and_a_flag_without_its_error():
    text = " ".join(flag_paragraphs(designed(ratio0=0.70, se0=0.1, below0=True)))
    assert ("**EKF on c (MSE / floor^2 0.700 +- 0.100), 3.0 s.e. below 1: RMSE 10.90 m against the floor 8.00 m is "
            "below even that floor, beyond its Monte Carlo error") in text
    old = designed()
    for key in ("mse_over_bound", "mse_over_bound_se", "mse_over_q0_bound", "mse_over_q0_bound_se"):
        del old["cases"]["c"]["methods"]["EKF"][key]  # results.json written before the error was kept
    text = " ".join(flag_paragraphs(old))
    assert "as these results recorded it, without its Monte Carlo error" in text and "beyond the Monte" not in text
    assert warning_lines(old) == ["warning   EKF on c below its filtering bound as recorded (no Monte Carlo error in "
                                  "the results)"]
    assert "(below its bound; no Monte Carlo error recorded!)" in "\n".join(_case_lines(old))


def _case_lines(res):
    from pmsr_nn.harness.report.bound_tables import case_table

    r = Results.from_dict(res)
    return case_table("c", r.cases["c"], None, "paper", False)


def test_diverged_runs_are_flagged_one_line_each():
    res = designed(below=False)
    res["cases"]["c"]["methods"]["EKF"]["diverged_runs"] = 2
    assert warning_lines(res) == ["warning   EKF on c: 2 of 5 runs diverged (position RMSE above 1000 m or not "
                                  "finite; kept in the averages)"]
    assert "EKF 2/5 on c" in " ".join(flag_paragraphs(res))
    assert warning_lines(designed(below=False)) == []


def test_cells_carry_their_standard_error_where_the_results_hold_it():
    res = designed(below=False)
    assert summary_table(res, None, "", False)[2] == "| EKF | 10.90 |"  # no standard error recorded
    with_se = copy.deepcopy(res)
    with_se["cases"]["c"]["methods"]["EKF"]["rmse_pos_se_m"] = 0.8
    assert summary_table(with_se, None, "", False)[2] == "| EKF | 10.90 ± 0.80 |"
    table = "\n".join(multi_target_tables(sampled(), None, "paper"))
    assert "| 150.0 ± 13.2: 50 / 30 / 20 |" in table  # GOSPA and its standard error (13.25 to one decimal)
    assert "| PCRB | filtering bound (association known) | 20.0 |" in table


def test_write_report_renders_the_same_from_the_dict_and_from_the_typed_results(tmp_path):
    import numpy as np
    from types import SimpleNamespace

    from pmsr_nn.harness.report.document import write_report

    res = designed()
    res["settings"].update({"recipe": "datasets/r.yaml", "variant": "envelope", "q_psd": 0.1,
                            "noise": {"range_m": 30.0, "range_rate_mps": 2.0, "azimuth_deg": 3.0}})
    res["definitions"] = {"rmse_pos_m": "Eq. 31"}
    res["environment"] = {k: k for k in ("pmsr_nn", "torch", "machine", "device", "threads", "date", "commit",
                                         "command")}
    truth = np.linspace([0.0, 0.0], [4000.0, 3000.0], 4)[:, None, :]
    examples = {"c": {"truth": truth, "EKF": truth[:, 0] + 10.0}}
    geometry = SimpleNamespace(transmitters=[], receivers=[])
    texts = []
    for i, given in enumerate((res, Results.from_dict(res))):
        out = tmp_path / str(i)
        out.mkdir()
        files = write_report(given, out, examples, geometry, None, None)
        assert {f.name for f in files} == {"report.md", "c_rmse.png", "trajectories.png"}
        texts.append((out / "report.md").read_text())
    assert texts[0] == texts[1]
    assert "| EKF | yes | **10.90** (below its bound!) | 0.200 | 12.34 (filtering) |" in texts[0]
    assert "4.0 s.e. below 1: RMSE 10.90 m against the bound 12.34 m" in texts[0]


def test_every_recorded_results_json_reads_through_the_typed_results():
    """The strict reading (types, non-negative standard errors) refuses none of the recorded studies."""
    import json

    read = 0
    for path in sorted((ROOT / "evaluate" / "results").rglob("results.json")):
        res = json.loads(path.read_text())
        if "cases" in res:  # the ablations' and the bound studies' tables are not a scenario's results
            r = Results.from_dict(res, source=str(path))
            assert all(row.rmse_pos_m is not None for _, _, row in r.rows()), path
            read += 1
    assert read >= 20
