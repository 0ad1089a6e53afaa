"""The report's figure of each row's tracks (small multiples): per case scored as tracks, one panel
per row with run 0's truth in grey, every track mapped to a target in its own colour and the
tracks the report counts as false marked, split into duplicates and the rest.

A track's class comes from the mapping the report's track table counts on
(:func:`~pmsr_nn.metrics.persistent_assignment`, cut-off ``c`` and order ``p`` of the scenario's
set metrics): ``mapped`` where it is mapped to a target at some scan; otherwise it is one of the
report's false tracks (``false_tracks_per_run``: never matched to any target), drawn as a
``duplicate`` where at half its scans or more it lies within ``c`` of a living target (beside a
target another track holds: a second track on a drone, or a ghost) and as ``false`` elsewhere
(started on clutter, or wandered off). Positions in metres, drawn in km.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ...metrics import persistent_assignment
from ..results.typed import Case, Results
from .figures import pyplot, save_figure

CLASSES = ("mapped", "duplicate", "false")
"""A track's class (module docstring)."""

DUPLICATE_SHARE = 0.5
"""An unmapped track within ``c`` of a living target at this share of its scans or more is a duplicate."""

PANEL_IN = 3.4
"""Side of a panel (inches)."""

PALETTE = ("tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "black",
           "navy", "darkgreen", "indigo", "saddlebrown", "darkmagenta", "teal")
"""The tracks mapped to a target take these colours in turn: dark ones, none of them the orange and
red of :data:`STYLE`, each readable on the light grey of the truth (tab20's light shades were not)."""

STYLE = {"duplicate": {"color": "darkorange", "ls": "--", "marker": "D"},
         "false": {"color": "crimson", "ls": ":", "marker": "x"}}
"""How the report's false tracks are drawn (a marker at each one's first scan)."""


@dataclass(frozen=True)
class TrackClasses:
    """Run 0's tracks of one row: ``slots`` the track slots that exist at some scan, ``kind`` each
    one's class (:data:`CLASSES`)."""

    slots: list[int]
    kind: list[str]

    def count(self, kind: str) -> int:
        return sum(k == kind for k in self.kind)


def classify_tracks(truth: np.ndarray, tracks: np.ndarray, c: float, p: float) -> TrackClasses:
    """The class of each track of one run (module docstring): ``truth (K, N, D)`` and ``tracks
    (K, M, D)`` in metres (the scored position columns, as the mapping uses them), NaN where a target does not live or a track does not exist; ``c`` (m)
    and ``p`` the set metrics' cut-off and order."""
    K = min(len(truth), len(tracks))
    truth, tracks = truth[:K], tracks[:K]
    alive, exists = np.isfinite(truth).all(-1), np.isfinite(tracks).all(-1)  # (K, N), (K, M)
    t = torch.as_tensor(np.nan_to_num(truth))[None]
    e = torch.as_tensor(np.nan_to_num(tracks))[None]
    mapping = persistent_assignment(e, torch.as_tensor(exists)[None], t, torch.as_tensor(alive)[None], c, p)[0].numpy()
    gap = np.linalg.norm(np.nan_to_num(tracks)[:, :, None] - np.nan_to_num(truth)[:, None], axis=-1)  # (K, M, N)
    near = (np.where(alive[:, None, :], gap, np.inf) < c).any(-1) & exists  # (K, M)
    slots, kind = [], []
    for m in np.flatnonzero(exists.any(0)):
        slots.append(int(m))
        if (mapping[:, m] >= 0).any():
            kind.append("mapped")
        else:
            kind.append("duplicate" if near[:, m].sum() >= DUPLICATE_SHARE * exists[:, m].sum() else "false")
    return TrackClasses(slots, kind)


def _as_tracks(est) -> np.ndarray:
    """Estimates ``(K, D)`` or ``(K, M, D)`` as ``(K, M, D)``."""
    est = np.asarray(est, dtype=float)
    return est[:, None] if est.ndim == 2 else est


def drawn_cases(res: Results | dict) -> list[str]:
    """The cases that get the figure: several targets, or some row that starts its own tracks."""
    results = Results.of(res)
    return [n for n, case in results.cases.items()
            if len(case.targets) > 1 or any(r.tracks is not None for r in case.methods.values())]


def _rows(case: Case, ex: dict) -> list[str]:
    """The rows of run 0 with positions to draw, in the results' order."""
    return [m for m in case.methods if m in ex]


def plot_case_tracks(res: Results | dict, examples: dict, name: str, path: Path) -> Path | None:
    """The figure of case ``name`` (module docstring; ``examples[name]``: ``truth (K, N, D)`` and
    per row ``(K, D)`` or ``(K, M, D)``, m; classified in all ``D`` position columns, drawn in the
    first two, east and north): one panel per row, every panel the same window (the
    truth's extent with a margin; a track beyond it is cut, its count in the panel's title).
    Constrained layout, the legend below the panels inside the figure. None where run 0 has no
    row to draw."""
    results = Results.of(res)
    case, ex = results.cases[name], examples.get(name, {})
    rows = _rows(case, ex)
    if not rows or "truth" not in ex:
        return None
    sm = results.settings.set_metrics
    c, p = (sm.c_m, sm.p) if sm is not None else (1000.0, 2.0)  # a scenario's defaults where none is recorded
    truth = np.asarray(ex["truth"], dtype=float)
    plt = pyplot()
    ncols = min(4, len(rows))
    nrows = math.ceil(len(rows) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(PANEL_IN * ncols, PANEL_IN * nrows + 1.3), squeeze=False,
                             layout="constrained")
    pts = truth[..., :2].reshape(-1, 2) / 1e3  # drawn east and north (a 3-D study's height is not)
    pts = pts[np.isfinite(pts).all(1)]
    lo, hi = (pts.min(0), pts.max(0)) if len(pts) else (np.zeros(2), np.ones(2))
    centre, side = 0.5 * (lo + hi), max(float((hi - lo).max()), 1e-3) * 1.16
    palette = lambda i: PALETTE[i % len(PALETTE)]
    drawn = []  # per panel: its axes, its tracks (km) and its counts
    for ax, m in zip(axes.flat, rows):
        tracks = _as_tracks(ex[m])
        cls = classify_tracks(truth, tracks, c, p)
        for t in range(truth.shape[1]):
            ax.plot(truth[:, t, 0] / 1e3, truth[:, t, 1] / 1e3, color="0.72", lw=3.0, solid_capstyle="round", zorder=1)
        colour = 0
        for slot, kind in zip(cls.slots, cls.kind):
            xy = tracks[:, slot, :2] / 1e3
            if kind == "mapped":
                ax.plot(xy[:, 0], xy[:, 1], color=palette(colour), lw=1.0, zorder=3)
                colour += 1
                continue
            st = STYLE[kind]
            ax.plot(xy[:, 0], xy[:, 1], color=st["color"], ls=st["ls"], lw=1.2, zorder=4)
            first = xy[np.isfinite(xy).all(1)][0]
            ax.plot(*first, color=st["color"], marker=st["marker"], ms=6, ls="none", zorder=5)
        counts = f"{cls.count('mapped')} on targets, {cls.count('duplicate')} duplicate, {cls.count('false')} false"
        ax.set_title(f"{textwrap.shorten(m, 48)}\n{counts}", fontsize=8)  # two lines in every panel
        drawn.append((ax, [tracks[:, slot, :2] / 1e3 for slot in cls.slots], counts))
        ax.set(xlim=(centre[0] - side / 2, centre[0] + side / 2), ylim=(centre[1] - side / 2, centre[1] + side / 2))
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelsize=7)
    for i, ax in enumerate(axes.flat):
        if i >= len(rows):
            ax.set_visible(False)
        elif i + ncols >= len(rows):  # the lowest panel of its column
            ax.set_xlabel("east (km)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("north (km)", fontsize=8)
    line = lambda **kw: plt.Line2D([], [], **kw)
    handles = [line(color="0.72", lw=3.0), line(color=palette(0), lw=1.0),
               line(color=STYLE["duplicate"]["color"], ls="--", marker="D", ms=5),
               line(color=STYLE["false"]["color"], ls=":", marker="x", ms=6)]
    labels = ["truth", "a track mapped to a target (one colour each)",
              f"duplicate: never mapped, within {c:g} m of a living target at half its scans (marker: first scan)",
              "false: never mapped, away from the targets (marker: first scan)"]
    fig.legend(handles, labels, loc="outside lower center", ncol=2, fontsize=8, frameon=False)
    fig.suptitle(textwrap.fill(f"{case.title}: each row's tracks in run 0", 90), fontsize=10)
    _equal_scales(fig, [ax for ax, _, _ in drawn], centre, side)
    for ax, tracks, counts in drawn:  # the window is final: say how many tracks lie wholly outside it
        lo_w, hi_w = np.array([ax.get_xlim()[0], ax.get_ylim()[0]]), np.array([ax.get_xlim()[1], ax.get_ylim()[1]])
        outside = sum(not bool((np.isfinite(xy).all(1) & (xy >= lo_w).all(1) & (xy <= hi_w).all(1)).any())
                      for xy in tracks)
        if outside:
            ax.set_title(f"{ax.get_title()} ({outside} outside the frame)", fontsize=8)
    return save_figure(fig, path)


def _equal_scales(fig, panels: list, centre: np.ndarray, side: float) -> None:
    """Widen each panel's square window (``centre``, ``side``, km) along its box's longer side, once
    the layout has placed the boxes: one km is as long east as north, and every panel (every box
    the same size) keeps the same window."""
    fig.canvas.draw()  # runs the constrained layout
    W, H = fig.get_size_inches()
    for ax in panels:
        box = ax.get_position()
        ratio = (box.width * W) / (box.height * H)
        half = 0.5 * side * np.array([max(ratio, 1.0), max(1.0 / ratio, 1.0)])
        ax.set(xlim=(centre[0] - half[0], centre[0] + half[0]), ylim=(centre[1] - half[1], centre[1] + half[1]))
