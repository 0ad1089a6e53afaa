"""Report figures read at a glance: shared extents, legends and titles inside the figure and off the
data, units on every axis, a zoomed inset where estimates lie metres off the truth on a km panel."""

import numpy as np
import pytest

from pmsr_nn.harness.report import figures, trajectory_figure
from pmsr_nn.harness.report.trajectory_figure import INSET_BELOW, INSET_SIZE, INSET_WINDOW, estimate_distance
from pmsr_nn.simulation.recipe import TrackRecipe
from pmsr_nn.simulation.tracks import build_models


@pytest.fixture(scope="module")
def geometry():
    return build_models(TrackRecipe())[1].geometry


def _line(start, end, n=50):
    return np.linspace(start, end, n)


def _inside_figure(fig, artist) -> bool:
    """Whether ``artist``'s drawn box lies within the figure's (pixels)."""
    box = artist.get_window_extent(fig.canvas.get_renderer())
    return box.x0 >= 0 and box.y0 >= 0 and box.x1 <= fig.bbox.width and box.y1 <= fig.bbox.height


def _titles_and_legends(fig) -> list:
    """Every title and legend of the figure, its panels and their insets."""
    axes = [a for ax in fig.axes for a in (ax, *ax.child_axes)]
    out = [ax.title for ax in axes if ax.get_title()] + list(fig.legends)
    out += [ax.get_legend() for ax in axes if ax.get_legend() is not None]
    return out + ([fig._suptitle] if fig._suptitle is not None else [])


def test_trajectory_panels_share_one_scale_and_keep_legends_off_the_data(captured, tmp_path, geometry):
    # A long straight path and a short wiggly one: the short one must not be zoomed in on.
    long = _line([0.0, 0.0], [8000.0, 2000.0])[:, None, :]
    short = _line([3000.0, 3000.0], [3200.0, 3100.0])[:, None, :]
    res = {"cases": {"long": {"title": "long"}, "short": {"title": "short"}}}
    examples = {"long": {"truth": long, "EKF": long[:, 0] + 300.0},
                "short": {"truth": short, "EKF": short[:, 0] - 200.0, "MDFNN": short[:, 0] + 500.0}}
    trajectory_figure.plot_trajectories(res, examples, geometry, tmp_path / "t.png")
    (fig,) = captured
    overview, *panels = fig.axes  # estimates hundreds of metres off on an 8 km panel: no inset
    widths = [np.diff(ax.get_xlim())[0] for ax in panels]
    heights = [np.diff(ax.get_ylim())[0] for ax in panels]
    assert widths[0] == pytest.approx(widths[1]) and heights[0] == pytest.approx(heights[1])
    assert widths[0] >= 8.0  # km: the long path fits
    for ax in panels:
        assert ax.get_legend() is None  # one figure legend below the panels
    assert {t.get_text() for t in fig.legends[0].get_texts()} == {"truth", "EKF", "MDFNN"}
    # The same method has the same colour in every panel.
    colour = {ax: {ln.get_label(): ln.get_color() for ln in ax.get_lines()} for ax in panels}
    assert colour[panels[0]]["EKF"] == colour[panels[1]]["EKF"] != colour[panels[1]]["MDFNN"]
    for ax in fig.axes:
        assert "(km)" in ax.get_xlabel() and "(km)" in ax.get_ylabel()


def test_estimate_distance_is_the_median_gap_to_the_nearest_living_target():
    truth = np.stack([_line([0.0, 0.0], [10.0, 0.0], 11), _line([0.0, 5.0], [10.0, 5.0], 11)], axis=1)  # (K, 2, 2)
    est = truth.copy()
    est[:, 0, 1] += 0.03  # 30 m off target 0 (km)
    est[:, 1, 1] -= 0.05  # 50 m off target 1
    est[3, 1] = np.nan  # a scan without that track: not counted
    # 11 gaps of 0.03 and 10 of 0.05: the median is the 11th, 0.03
    assert estimate_distance(truth, [est]) == pytest.approx(0.03, rel=1e-12)
    assert np.isnan(estimate_distance(truth, [np.full_like(est, np.nan)]))


def test_metres_off_on_a_km_panel_get_a_zoomed_inset(captured, tmp_path, geometry):
    truth = _line([0.0, 0.0], [8000.0, 6000.0], 101)[:, None, :]  # a 10 km path
    normal = np.array([-0.6, 0.8])  # across the path
    res = {"cases": {"c": {"title": "c"}}}
    examples = {"c": {"truth": truth, "EKF": truth[:, 0] + 10.0 * normal, "MDFNN": truth[:, 0] - 15.0 * normal}}
    trajectory_figure.plot_trajectories(res, examples, geometry, tmp_path / "t.png")
    (fig,) = captured
    overview, panel = fig.axes
    (inset,) = panel.child_axes
    side = np.diff(panel.get_xlim())[0]  # km
    gap = estimate_distance(truth / 1e3, [examples["c"][m][:, None] / 1e3 for m in ("EKF", "MDFNN")])
    assert gap == pytest.approx(0.0125, rel=1e-9)  # the median of 10 m and 15 m gaps
    assert gap < INSET_BELOW * side  # metres on a km panel: the case for an inset
    # The inset's window is INSET_WINDOW median gaps wide, centred on the path's middle scan.
    assert np.diff(inset.get_xlim())[0] == pytest.approx(INSET_WINDOW * gap, rel=1e-9)
    assert np.mean(inset.get_xlim()) == pytest.approx(4.0, rel=1e-9)
    assert np.mean(inset.get_ylim()) == pytest.approx(3.0, rel=1e-9)
    # It holds the truth and every method, its box a corner of the panel.
    assert len(inset.get_lines()) == 3
    box, outer = inset.get_position(), panel.get_position()
    assert box.width == pytest.approx(INSET_SIZE * outer.width, rel=1e-6)
    # The panel without an inset: the same flights with the estimates 300 m off (3 % of the side).
    captured.clear()
    examples = {"c": {"truth": truth, "EKF": truth[:, 0] + 300.0 * normal}}
    trajectory_figure.plot_trajectories(res, examples, geometry, tmp_path / "t.png")
    assert captured[0].axes[1].child_axes == []


def test_trajectory_titles_and_legends_lie_inside_the_figure(captured, tmp_path, geometry):
    truth = _line([0.0, 0.0], [9000.0, 3000.0])[:, None, :]
    methods = ["EKF", "UKF", "SI+KF", "PF", "IMM", "MDFNN [seed 0]", "KalmanNet [seed 0]", "S-MSJPDA"]
    long_title = "a designed flight with a long descriptive title that has to wrap over lines"
    res = {"cases": {n: {"title": long_title} for n in ("a", "b", "c")}}
    examples = {n: {"truth": truth, **{m: truth[:, 0] + 4.0 * (i + 1) for i, m in enumerate(methods)}}
                for n in res["cases"]}
    trajectory_figure.plot_trajectories(res, examples, geometry, tmp_path / "t.png")
    (fig,) = captured
    boxes = _titles_and_legends(fig)
    assert len(boxes) == 4 + 1 + 1 + 3  # panel titles, the figure legend, the overview's, the insets' titles
    for artist in boxes:
        assert _inside_figure(fig, artist), artist
    # The figure legend lies below every panel, tick labels included: it covers no data or label.
    renderer = fig.canvas.get_renderer()
    legend = fig.legends[0].get_window_extent(renderer)
    assert legend.y1 <= min(ax.get_tightbbox(renderer).y0 for ax in fig.axes[1:4])


def _rmse_results(n_targets: int, steps: int = 20) -> dict:
    curve = list(np.linspace(30, 10, steps))
    per = (lambda c: c) if n_targets == 1 else (lambda c: [c] * n_targets)
    methods = ("EKF", "UKF", "MDFNN", "KalmanNet", "S-MSJPDA")
    case = {"title": "a case with a long title", "steps": steps, "targets": [f"drone {i}" for i in range(n_targets)],
            "methods": {m: {"causal": True} for m in methods},
            "curves": {"rmse_pos_m": {m: per(curve) for m in methods}, "pcrb_pos_m": per(list(np.linspace(25, 9, steps))),
                       "pcrb_q0_pos_m": per(list(np.linspace(20, 5, steps)))}}
    return {"settings": {"dt_s": 1.0, "warmup_steps": 5}, "mc_runs": 3, "cases": {"c": case}}


def test_rmse_legend_sits_outside_the_axes(captured, tmp_path):
    figures.plot_rmse(_rmse_results(1), tmp_path)
    (fig,) = captured
    (ax,) = fig.axes
    box, legend = ax.get_window_extent(), ax.get_legend().get_window_extent()
    assert legend.x0 >= box.x1  # right of the data
    assert ax.get_xlabel() == "time (s)" and ax.get_ylabel() == "position RMSE (m)"
    for artist in _titles_and_legends(fig):
        assert _inside_figure(fig, artist), artist


def test_per_target_rmse_and_set_figures_keep_title_and_legend_inside(captured, tmp_path):
    res = _rmse_results(7)
    figures.plot_rmse(res, tmp_path)
    steps = res["cases"]["c"]["steps"]
    res["settings"]["set_metrics"] = {"c_m": 500.0, "p": 2.0}
    res["cases"]["c"]["curves"].update({"cardinality_truth": [7] * steps, "set": {
        m: {"ospa_m": [100.0] * steps, "cardinality": [6.5] * steps} for m in res["cases"]["c"]["methods"]}})
    figures.plot_set_metrics(res, tmp_path)
    for fig in captured:
        renderer = fig.canvas.get_renderer()
        assert fig._suptitle is not None and len(fig.legends) == 1
        for artist in _titles_and_legends(fig):
            assert _inside_figure(fig, artist), artist
        legend = fig.legends[0].get_window_extent(renderer)
        assert legend.y1 <= min(ax.get_tightbbox(renderer).y0 for ax in fig.axes if ax.get_visible())
