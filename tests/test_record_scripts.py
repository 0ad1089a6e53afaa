"""The scripts that keep a record for a figure of evaluate/RESULTS.md (issue 60) reproduce the
committed record: the set tracker's "no target" GOSPA and the innovation bias test's burn-in
restarts."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "evaluate" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_empty_set_gospa_of_seed_0_is_the_records(tmp_path):
    """Seed 0's validation scenes drawn again: each batch's targets per window are the record's, and
    answering "no target" scores sqrt(c^2 / 2 x targets) per batch (c the cut-off), their mean the
    record's 603.6 m."""
    record = json.loads((ROOT / "evaluate/results/set_tracker_empty_gospa.json").read_text())
    out = tmp_path / "empty.json"
    assert _script("set_tracker_empty_gospa").main(["--seeds", "0", "--json", str(out)]) == 0
    seed0 = json.loads(out.read_text())["seeds"]["0"]
    want = record["seeds"]["0"]
    assert [b["targets_per_window"] for b in seed0["batches"]] == [b["targets_per_window"] for b in want["batches"]]
    c = record["cutoff_m"]
    by_hand = sum(math.sqrt(c * c / 2 * b["targets_per_window"]) for b in want["batches"]) / len(want["batches"])
    assert seed0["gospa_empty_set_m"] == pytest.approx(by_hand, rel=1e-12)
    assert seed0["gospa_empty_set_m"] == pytest.approx(want["gospa_empty_set_m"], rel=1e-12)


@pytest.mark.integration
def test_the_burn_in_restarts_are_the_records(tmp_path):
    """The runs in which the test restarts a right track, at burn-ins 0 and 20: the record's counts
    (the draws are seeded: the same runs, the same tracks)."""
    record = json.loads((ROOT / "evaluate/results/innovation_bias_burn_in.json").read_text())
    out = tmp_path / "burn_in.json"
    assert _script("innovation_bias_burn_in").main(["--burn-ins", "0,20", "--json", str(out)]) == 0
    got = json.loads(out.read_text())
    assert got["restarted_runs"] == {b: record["restarted_runs"][b] for b in ("0", "20")}
    assert got["runs_with_more_tracks_without_the_test"] == record["runs_with_more_tracks_without_the_test"]


def test_a_negative_burn_in_is_refused(capsys):
    assert _script("innovation_bias_burn_in").main(["--burn-ins", "5,-1"]) == 2
    assert "--burn-ins" in capsys.readouterr().err
