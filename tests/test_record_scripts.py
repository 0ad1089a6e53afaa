"""The scripts that keep a record for a figure of evaluate/RESULTS.md (issue 60) reproduce the
committed record: the innovation bias test's burn-in restarts. (The set tracker's "no target"
GOSPA script left the package with the set tracker under issue 56; its record stays.)"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "evaluate" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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
