"""The figure of each row's tracks (issue 55, item 5): a track's class by hand and against the
report's false-track count, one panel per row, the title and legend inside the figure, and the
report linking it in place of the one-panel trajectories of the case."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from pmsr_nn.harness.report.track_figure import classify_tracks, plot_case_tracks
from pmsr_nn.metrics import persistent_assignment, track_scores

from figure_check import assert_drawn_png
from test_figures import _inside_figure, _titles_and_legends

ROOT = Path(__file__).resolve().parents[1]

NAN = float("nan")


def _scene():
    """Two targets 2 km apart flying east for 40 scans (m); target B lives from scan 10. Tracks:
    0 on A (5 m off), 1 beside A (40 m off, at every scan A lives: A is held by track 0), 2 on B,
    3 far from both (5 km north), 4 beside A for 10 scans then 3 km away for 30 (near at a
    quarter of its scans: false), 5 on A but only from scan 20 on, and never beside (10 m behind
    track 0: never mapped, a duplicate)."""
    k = np.arange(40, dtype=float)
    A = np.stack([k * 20.0, np.zeros(40)], -1)
    B = np.stack([k * 20.0, np.full(40, 2000.0)], -1)
    B[:10] = NAN
    truth = np.stack([A, B], 1)  # (K, N, 2)
    far = np.stack([k * 20.0, np.full(40, 5000.0)], -1)
    wander = A + np.array([0.0, 40.0])
    wander[10:, 1] = 3000.0
    late = A + np.array([-10.0, 0.0])
    late[:20] = NAN
    tracks = np.stack([A + [0.0, 5.0], A + [0.0, 40.0], B + [0.0, -5.0], far, wander, late], 1)  # (K, 6, 2)
    return truth, tracks


def test_track_classes_by_hand_and_the_reports_false_tracks():
    truth, tracks = _scene()
    cls = classify_tracks(truth, tracks, 500.0, 2.0)
    assert cls.slots == [0, 1, 2, 3, 4, 5]
    assert cls.kind == ["mapped", "duplicate", "mapped", "false", "false", "duplicate"]
    # duplicates and false tracks together are the report's false tracks (never mapped to a target)
    alive, exists = np.isfinite(truth).all(-1), np.isfinite(tracks).all(-1)
    t, e = (torch.as_tensor(np.nan_to_num(a))[None] for a in (truth, tracks))
    a, x = torch.as_tensor(alive)[None], torch.as_tensor(exists)[None]
    ts = track_scores(persistent_assignment(e, x, t, a, 500.0, 2.0), x, a)
    assert float(ts.false_tracks[0]) == cls.count("duplicate") + cls.count("false") == 4
    # a smaller cut-off (30 m): track 1 (40 m off) is no longer within it, a false track
    assert classify_tracks(truth, tracks, 30.0, 2.0).kind[1] == "false"


def _results(rows: list[str]) -> dict:
    methods = {m: {"kind": "x", "ospa_m": 1.0, "confirmed_tracks_per_target": 1.0} for m in rows}
    return {"settings": {"dt_s": 1.0, "warmup_steps": 0, "set_metrics": {"c_m": 500.0, "p": 2.0}}, "mc_runs": 1,
            "cases": {"c": {"title": "two drones with a long descriptive title that has to wrap somewhere in the figure",
                            "steps": 40, "targets": ["A", "B"], "methods": {**methods, "PCRB": {"kind": "pcrb"}}}}}


def test_one_panel_per_row_with_title_and_legend_inside_the_figure(captured, tmp_path):
    truth, tracks = _scene()
    rows = ["EKF", "S-MSJPDA", "PMHT", "a row with a rather long name", "SMC-PHD + GTDA"]
    examples = {"c": {"truth": truth, **{m: tracks for m in rows}, "@phd": tracks}}
    plot_case_tracks(_results(rows), examples, "c", tmp_path / "c_tracks.png")
    (fig,) = captured
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title().split("\n")[0] for ax in panels] == rows  # no PCRB, no "@" entry
    # track 3 (5 km north) lies beyond the window of the truth: counted, and said to be outside
    assert panels[0].get_title().split("\n")[1] == "2 on targets, 2 duplicate, 2 false (1 outside the frame)"
    windows = {(round(float(np.diff(ax.get_xlim())[0]), 9), round(float(np.diff(ax.get_ylim())[0]), 9)) for ax in panels}
    assert len(windows) == 1  # one window for every panel
    W, H = fig.get_size_inches()
    for ax in panels:  # a km as long east as north (to the layout's last move of a tick label: 2 %)
        box = ax.get_position()
        east = np.diff(ax.get_xlim())[0] / (box.width * W)
        assert east == pytest.approx(np.diff(ax.get_ylim())[0] / (box.height * H), rel=0.02)
    boxes = _titles_and_legends(fig)
    assert len(boxes) == len(rows) + 2  # the panels' titles, the legend, the figure's title
    for artist in boxes:
        assert _inside_figure(fig, artist), artist
    renderer = fig.canvas.get_renderer()
    top = max(t.get_window_extent(renderer).y1 for t in fig.legends[0].get_texts())
    assert top <= min(ax.get_tightbbox(renderer).y0 for ax in panels)  # the entries below every panel and its labels


@pytest.mark.integration
@pytest.mark.figures
def test_the_report_links_the_figure_and_draws_it(tmp_path):
    """write_report on dense_crossing's recorded results (written before trajectory GOSPA and
    identity switches were kept: the report renders without the one and with label switches) with
    run 0 given for two of its rows: the case's figure written and linked, the trajectories figure
    left with its first panel (sensors and true paths) only."""
    import json

    from pmsr_nn.harness.report.document import write_report

    res = json.loads((ROOT / "evaluate" / "results" / "dense_crossing" / "results.json").read_text())
    truth, tracks = _scene()
    examples = {"dense_crossing": {"truth": truth, "S-MSJPDA": tracks, "PMHT": tracks[:, :3]}}
    geometry = SimpleNamespace(transmitters=[SimpleNamespace(position_m=[0.0, 0.0])],
                               receivers=[SimpleNamespace(position_m=[500.0, -500.0])])
    files = write_report(res, tmp_path, examples, geometry, None, None)
    report = (tmp_path / "report.md").read_text()
    assert "Trajectory GOSPA" not in report and "label switches / run" in report and "ID switches" not in report
    assert "![tracks of every row, dense_crossing](dense_crossing_tracks.png)" in report
    assert tmp_path / "dense_crossing_tracks.png" in files
    assert_drawn_png(tmp_path / "dense_crossing_tracks.png")
    img = assert_drawn_png(tmp_path / "trajectories.png")
    assert img.shape[1] < img.shape[0] * 1.2  # one panel (with its legend below), not one per case besides it


def test_a_3d_studys_tracks_are_classed_in_3d_and_drawn_east_and_north(captured, tmp_path):
    """Positions with a height column (a 3-D study): the classes are those of the 2-D scene
    when every height is equal, and a duplicate lifted 600 m above its target (beyond c = 500 m)
    becomes false; the panels draw east and north (the window of the 2-D scene)."""
    truth, tracks = _scene()
    up = lambda a, h: np.concatenate([a, np.full(a.shape[:-1] + (1,), h)], -1)
    truth3, tracks3 = up(truth, 100.0), up(tracks, 100.0)
    assert classify_tracks(truth3, tracks3, 500.0, 2.0).kind == classify_tracks(truth, tracks, 500.0, 2.0).kind
    tracks3[:, 1, 2] += 600.0
    assert classify_tracks(truth3, tracks3, 500.0, 2.0).kind[1] == "false"
    plot_case_tracks(_results(["PMHT-3D"]), {"c": {"truth": truth3, "PMHT-3D": tracks3}}, "c", tmp_path / "c.png")
    plot_case_tracks(_results(["PMHT-3D"]), {"c": {"truth": truth, "PMHT-3D": tracks}}, "c", tmp_path / "d.png")
    three, two = (fig.axes[0] for fig in captured)
    assert three.get_xlim() == two.get_xlim() and three.get_ylim() == two.get_ylim()
