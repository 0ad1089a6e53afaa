"""evaluate/reproduce_records.py: the issue-54 regression tool that re-runs the quick recorded
studies and compares them with their records."""

from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("reproduce_records", ROOT / "evaluate" / "reproduce_records.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_record_reproduces_itself_and_one_changed_value_is_caught(tool):
    """The record against itself reproduces; one headline figure, or one other value, moved by a
    part in 1e6 (far above the 1e-9 of 'the same') does not."""
    res = json.loads((ROOT / "evaluate/results/dense_crossing_bp/results.json").read_text())
    assert tool.verdict(res, copy.deepcopy(res))["reproduces"]
    case, row = next((c, m) for c, cc in res["cases"].items() for m in cc["methods"])
    moved = copy.deepcopy(res)
    moved["cases"][case]["methods"][row]["gospa_m"] *= 1 + 1e-6
    v = tool.verdict(res, moved)
    assert not v["reproduces"] and v["other_differ"] == 0 and "same" in v["headline"]
    moved = copy.deepcopy(res)
    moved["cases"][case]["methods"][row]["false_tracks_per_run"] += 1e-6
    v = tool.verdict(res, moved)
    assert not v["reproduces"] and v["other_differ"] == 1


def test_a_field_the_record_predates_is_counted_apart_and_does_not_fail_it(tool):
    """A record made before the code wrote some field (e.g. trajectory GOSPA) still reproduces on
    the values it has; the new field is counted, not compared."""
    res = json.loads((ROOT / "evaluate/results/dense_crossing_bp/results.json").read_text())
    case, row = next((c, m) for c, cc in res["cases"].items() for m in cc["methods"])
    older = copy.deepcopy(res)
    del older["cases"][case]["methods"][row]["false_tracks_per_run"]
    v = tool.verdict(older, res)
    assert v["reproduces"] and v["fields_the_record_predates"] == 1 and v["other_differ"] == 0
    v = tool.verdict(res, older)  # a field the re-run lacks is a difference
    assert not v["reproduces"] and v["other_differ"] == 1


def test_the_re_run_time_is_the_records_rows_seconds_times_runs(tool):
    res = {"cases": {"a": {"methods": {"X": {"seconds_per_run": 3.0, "runs": 10}, "bound": {"runs": 10}}},
                     "b": {"methods": {"Y": {"seconds_per_run": 1.5, "runs": 4}}}}}
    assert tool.recorded_minutes(res) == pytest.approx((30.0 + 6.0) / 60.0, rel=1e-12)


def test_only_studies_with_their_scenario_are_listed_and_an_unknown_name_is_refused(tool, tmp_path, capsys):
    names = tool.studies(None)
    assert "dense_crossing_bp" in names and "one_sky_bp_bank" not in names
    assert (ROOT / "evaluate/results/shared_drones_hybrid/results.json").is_file()
    assert "shared_drones_hybrid" not in names  # a record whose scenario has another name cannot be re-run by name
    assert tool.main(["--out", str(tmp_path / "new"), "--only", "no_such_study"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"reproduce_records: --only: no recorded study no_such_study (known: {', '.join(names)})"]
    assert not (tmp_path / "new").exists()


def test_an_out_folder_that_holds_something_is_refused_and_left_alone(tool, tmp_path, capsys):
    (tmp_path / "mine.txt").write_text("a user's file")
    assert tool.main(["--out", str(tmp_path), "--only", "fm_front_end"]) == 2
    assert "exists and is not an empty folder" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]
