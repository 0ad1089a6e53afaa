"""Report figures read at a glance: shared extents, legends outside the data, units on every axis."""

import numpy as np
import pytest

from pmsr_nn.harness import report
from pmsr_nn.simulation.recipe import TrackRecipe
from pmsr_nn.simulation.tracks import build_models


@pytest.fixture
def captured(monkeypatch):
    """The figures the report functions make, kept open instead of written."""
    figs = []

    def keep(fig, path, dpi=110, rect=None):
        fig.tight_layout(rect=rect)
        figs.append(fig)
        return path

    monkeypatch.setattr(report, "save_figure", keep)
    return figs


def _line(start, end, n=50):
    return np.linspace(start, end, n)


def test_trajectory_panels_share_one_scale_and_keep_legends_off_the_data(captured, tmp_path):
    # A long straight path and a short wiggly one: the short one must not be zoomed in on.
    long = _line([0.0, 0.0], [8000.0, 2000.0])[:, None, :]
    short = _line([3000.0, 3000.0], [3200.0, 3100.0])[:, None, :]
    res = {"cases": {"long": {"title": "long"}, "short": {"title": "short"}}}
    examples = {"long": {"truth": long, "EKF": long[:, 0] + 30.0},
                "short": {"truth": short, "EKF": short[:, 0] - 20.0, "MDFNN": short[:, 0] + 5.0}}
    report.plot_trajectories(res, examples, build_models(TrackRecipe())[1].geometry, tmp_path / "t.png")
    (fig,) = captured
    overview, *panels = fig.axes
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


def test_rmse_legend_sits_outside_the_axes(captured, tmp_path):
    t = 20
    res = {"settings": {"dt_s": 1.0, "warmup_steps": 5}, "mc_runs": 3,
           "cases": {"c": {"title": "c", "steps": t, "methods": {"EKF": {"causal": True}},
                           "curves": {"rmse_pos_m": {"EKF": list(np.linspace(30, 10, t))},
                                      "pcrb_pos_m": list(np.linspace(25, 9, t)),
                                      "pcrb_q0_pos_m": list(np.linspace(20, 5, t))}}}}
    report.plot_rmse(res, tmp_path)
    (fig,) = captured
    (ax,) = fig.axes
    fig.canvas.draw()
    box, legend = ax.get_window_extent(), ax.get_legend().get_window_extent()
    assert legend.x0 >= box.x1  # right of the data
    assert ax.get_xlabel() == "time (s)" and ax.get_ylabel() == "position RMSE (m)"
