"""The report's trajectory figure: the sensors and every case's true paths, then per case run 0's
truth and each method's estimates, with a zoomed inset where they lie metres apart on a km-scale
panel (Fig. 8 / 12 analogue). Cases scored as tracks get a figure per row instead
(:mod:`.track_figure`)."""

from __future__ import annotations

import textwrap
import warnings
from pathlib import Path

import numpy as np

from ..results.typed import Results
from .figures import method_colours, pyplot, save_figure

INSET_BELOW = 0.01
"""An inset is drawn where the median distance of the estimates to the truth is under this share of
the panel's side: at 4 inches a side, 1 % is under 3 points, the width of the truth's line."""

INSET_WINDOW = 20.0
"""The inset's window is this many median distances wide: the estimates sit about 5 % of its side
off the truth, a few times its lines' widths."""

INSET_SIZE = 0.4
"""The inset's side as a share of its panel's."""


def path_extent(paths: list[np.ndarray], margin: float = 0.08) -> tuple[np.ndarray, float]:
    """Centre ``(2,)`` and side (same units) of the square holding the finite points of ``paths``
    (each ``(K, ..., 2)``), with ``margin`` of the side added."""
    pts = np.concatenate([p.reshape(-1, 2) for p in paths if p.size]) if paths else np.zeros((1, 2))
    pts = pts[np.isfinite(pts).all(1)]
    if not len(pts):
        return np.zeros(2), 1.0
    lo, hi = pts.min(0), pts.max(0)
    return 0.5 * (lo + hi), max(float((hi - lo).max()), 1e-3) * (1 + 2 * margin)


def _as_tracks(est) -> np.ndarray:
    """Estimates ``(K, 2)`` or ``(K, M, 2)`` as ``(K, M, 2)``."""
    est = np.asarray(est, dtype=float)
    return est[:, None] if est.ndim == 2 else est


def estimate_distance(truth: np.ndarray, estimates: list[np.ndarray]) -> float:
    """Median over every estimate of its distance to the nearest living target at its scan (same
    units as the inputs; ``truth (K, N, 2)``, each estimate ``(K, M, 2)``, NaN where absent); NaN
    without a pair."""
    d = []
    for est in estimates:
        K = min(len(est), len(truth))
        gap = np.linalg.norm(est[:K, :, None, :] - truth[:K, None, :, :], axis=-1)  # (K, M, N)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # scans without an estimate or a target
            nearest = np.nanmin(np.where(np.isfinite(gap), gap, np.nan), axis=-1)
        d.append(nearest[np.isfinite(nearest)])
    d = np.concatenate(d) if d else np.zeros(0)
    return float(np.median(d)) if len(d) else float("nan")


def inset_window(truth: np.ndarray, distance: float, side: float) -> tuple[np.ndarray, float] | None:
    """Centre ``(2,)`` and side of the zoomed window on a stretch of the path, or None where the
    estimates can be told from the truth on the panel (``distance`` at least :data:`INSET_BELOW`
    of the panel's ``side``). The stretch: the first target's middle scan."""
    if not np.isfinite(distance) or distance <= 0 or distance >= INSET_BELOW * side:
        return None
    pts = truth[:, 0][np.isfinite(truth[:, 0]).all(1)]
    if not len(pts):
        return None
    return pts[len(pts) // 2], INSET_WINDOW * distance


def _emptiest_corner(ax, paths: list[np.ndarray]) -> tuple[float, float]:
    """Lower-left corner (axes fractions) of the :data:`INSET_SIZE` square in the panel's corner
    that holds the fewest path points."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    pts = np.concatenate([p.reshape(-1, 2) for p in paths if p.size]) if paths else np.zeros((0, 2))
    fx, fy = (pts[:, 0] - x0) / (x1 - x0), (pts[:, 1] - y0) / (y1 - y0)
    pad = 0.02
    corners = [(a, b) for b in (1 - INSET_SIZE - pad, pad) for a in (1 - INSET_SIZE - pad, pad)]
    inside = [np.sum((fx >= a) & (fx <= a + INSET_SIZE) & (fy >= b) & (fy <= b + INSET_SIZE)) for a, b in corners]
    return corners[int(np.argmin(inside))]


def _add_inset(ax, truth: np.ndarray, tracks: dict[str, np.ndarray], colours: dict, window) -> None:
    """A zoomed copy of the panel's lines on ``window`` (centre, side), in its emptiest corner,
    the zoomed area marked on the panel."""
    centre, w = window
    corner = _emptiest_corner(ax, [truth, *tracks.values()])
    inset = ax.inset_axes([*corner, INSET_SIZE, INSET_SIZE])
    for t in range(truth.shape[1]):
        inset.plot(truth[:, t, 0], truth[:, t, 1], "k", lw=1.6)
    for m, est in tracks.items():
        for t in range(est.shape[1]):
            inset.plot(est[:, t, 0], est[:, t, 1], color=colours[m], lw=0.9)
    inset.set(xlim=(centre[0] - w / 2, centre[0] + w / 2), ylim=(centre[1] - w / 2, centre[1] + w / 2), aspect="equal")
    inset.set_title(f"zoom: {1e3 * w:.0f} m wide", fontsize=7, pad=2)
    inset.tick_params(labelleft=False, labelbottom=False, length=0)
    ax.indicate_inset_zoom(inset, edgecolor="0.3")


def plot_trajectories(res: Results | dict, examples: dict, geometry, path: Path, skip=()) -> Path:
    """Sensors and every case's true paths, then per case run 0's truth and each method's
    estimates (``examples[case]``: ``truth (K, N, 2)`` and per method ``(K, 2)`` or ``(K, M, 2)``,
    m; drawn in km); the cases in ``skip`` (drawn per row by :mod:`.track_figure`) only in the
    first panel.

    The per-case panels share one extent: each is a square window of the same side (the largest
    case's true path, with a margin) centred on its own path, so every panel has the same scale
    and none is squashed. Where the estimates lie under :data:`INSET_BELOW` of that side off the
    truth, an inset zooms on a stretch of the path. Constrained layout, the legends below the
    panels: no title or legend is cut."""
    results = Results.of(res)
    plt = pyplot()
    every = list(results.cases)
    names = [n for n in every if n not in set(skip)]
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(3.8 * (len(names) + 1), 5.2), squeeze=False,
                             layout="constrained")
    axes = axes[0]
    ax0 = axes[0]
    for i, tx in enumerate(geometry.transmitters):
        ax0.plot(tx.position_m[0] / 1e3, tx.position_m[1] / 1e3, "k^", ms=9, label="transmitter" if i == 0 else None)
    for i, rx in enumerate(geometry.receivers):
        ax0.plot(rx.position_m[0] / 1e3, rx.position_m[1] / 1e3, "bv", ms=7, label="receiver" if i == 0 else None)
    truths = {n: np.asarray(examples.get(n, {}).get("truth", np.zeros((0, 1, 2))), dtype=float) / 1e3 for n in every}
    for j, name in enumerate(every):
        truth = truths[name]
        for t in range(truth.shape[1]):
            ax0.plot(truth[:, t, 0], truth[:, t, 1], color=f"C{j}", lw=1.6, label=name if t == 0 else None)
    ax0.set(xlabel="east (km)", ylabel="north (km)", title="sensors and true trajectories", aspect="equal")
    ax0.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, frameon=False)
    side = max(path_extent([truths[n]])[1] for n in names) if names else 1.0
    colours = method_colours(m for n in names for m in examples.get(n, {}) if m != "truth" and not m.startswith("@"))
    for ax, name in zip(axes[1:], names):
        ex = examples.get(name, {})
        truth = truths[name]
        for t in range(truth.shape[1]):
            ax.plot(truth[:, t, 0], truth[:, t, 1], "k", lw=2.2, label="truth" if t == 0 else None)
        tracks = {m: _as_tracks(ex[m]) / 1e3 for m in ex if m != "truth" and not m.startswith("@")}
        for m, est in tracks.items():  # one colour per method in every panel and figure
            for t in range(est.shape[1]):
                ax.plot(est[:, t, 0], est[:, t, 1], color=colours[m], lw=0.8, label=m if t == 0 else None)
        centre, _ = path_extent([truth])
        ax.set(xlim=(centre[0] - side / 2, centre[0] + side / 2), ylim=(centre[1] - side / 2, centre[1] + side / 2),
               xlabel="east (km)", ylabel="north (km)", aspect="equal",
               title=textwrap.fill(f"{results.cases[name].title}: run 0", 36))
        ax.grid(True, alpha=0.3)
        window = inset_window(truth, estimate_distance(truth, list(tracks.values())), side)
        if window is not None:
            _add_inset(ax, truth, tracks, colours, window)
    entries = {}  # every panel's methods (a case may run fewer), first handle per label
    for ax in axes[1:]:
        for h, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, h)
    if entries:
        fig.legend(list(entries.values()), list(entries), loc="outside lower center",
                   ncol=min(len(entries), 6), fontsize=8, frameon=False)
    return save_figure(fig, path)
