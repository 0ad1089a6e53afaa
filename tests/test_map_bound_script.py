"""evaluate/map_bound.py: the map bound of a scenario's cases beside a record's map rows. The
bound it prints is the one a run records (``rd_maps.bound_pos_m``); a scenario without maps is one
line and exit 2, nothing written."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from test_tbd_kinds import SMALL, tiny, write

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str):
    return subprocess.run([sys.executable, str(ROOT / "evaluate/map_bound.py"), *args], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=600)


@pytest.mark.integration
def test_the_bound_is_the_recorded_one_and_each_row_is_divided_by_it(tmp_path):
    d = tiny(mc_runs=1)
    d["methods"] = [{"name": "m5", "kind": "modified_icmb", "options": dict(SMALL)}]
    path = write(tmp_path, d)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "pmsr_nn.cli", "evaluate", str(path), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    res = json.loads((out / "results.json").read_text())
    bound = res["cases"]["c"]["rd_maps"]["bound_pos_m"][2]
    for case in res["cases"].values():  # a record made before the bound: the script supplies it
        del case["rd_maps"]["bound_pos_m"]
    (tmp_path / "old.json").write_text(json.dumps(res))
    proc = _run(str(path), "--record", str(tmp_path / "old.json"), "--json", str(tmp_path / "b.json"))
    assert proc.returncode == 0, proc.stderr
    fig = json.loads((tmp_path / "b.json").read_text())["cases"]["c"]
    assert fig["bound_last_m"] == pytest.approx(bound, rel=1e-12) and fig["last_frame"] == 3
    rms = res["cases"]["c"]["methods"]["m5"]["tbd"]["rms_pos_last_present_m"]
    assert fig["rows"]["m5"] == {"rms_pos_last_m": rms, "over_bound": pytest.approx(rms / bound, rel=1e-12)}
    assert f"map bound {bound:.1f} m at frame 3" in proc.stdout


def test_a_scenario_without_maps_is_one_line(tmp_path):
    d = tiny()
    del d["rd_maps"]
    d["methods"] = [{"name": "e", "kind": "ekf"}]
    path = write(tmp_path, d)
    before = sorted(p.name for p in tmp_path.iterdir())
    proc = _run(str(path), "--json", str(tmp_path / "b.json"))
    assert proc.returncode == 2 and proc.stderr.strip() == f"map_bound: error: {path} has no case with range-Doppler maps"
    assert sorted(p.name for p in tmp_path.iterdir()) == before
