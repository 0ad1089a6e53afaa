"""Plausibility of measurements handed to a tracker: is this what the geometry could produce?

A network or filter given numbers no sensor of its geometry can produce answers with confident
nonsense (finite states for azimuths in degrees, NaN for ranges of 1e300). These checks refuse
such input with the row and column named; ``pmsr track --force`` skips them.

Checked per column kind (measurement labels ``range_n``, ``range_rate_n``, ``azimuth_n``, ...):

* bistatic range ``r_n``: at least the pair's baseline (``r = |p - tx| + |p - rx| >= |tx - rx|``),
  less :data:`RANGE_SLACK_M` for noise;
* azimuth: inside ``[-pi, pi]`` (plus :data:`AZIMUTH_SLACK_RAD` for noise), so that degrees are
  caught;
* every column: inside the span the tracker was trained on, widened by
  :data:`SPAN_FACTOR` times that span on each side.
"""

from __future__ import annotations

import math

import torch

from .errors import MeasurementError
from .geometry import Geometry

RANGE_SLACK_M = 1_000.0
"""Bistatic-range noise is metres to tens of metres; a kilometre below the baseline is no noise."""

AZIMUTH_SLACK_RAD = 0.05
"""Azimuth noise of a few milliradians, with room for a noisy value just past +-pi."""

SPAN_FACTOR = 10.0
"""How far outside its training span a measurement may lie, in units of that span."""


def _kind(label: str) -> tuple[str, int | None]:
    base, _, idx = label.rpartition("_")
    if base and idx.isdigit():
        return base, int(idx) - 1
    return label, None


def check_measurements(z: torch.Tensor, columns: list[str], geometry: Geometry,
                       span: tuple[torch.Tensor, torch.Tensor] | None = None,
                       where=lambda b, k: f"sequence {b}, scan {k}") -> None:
    """Raise :class:`MeasurementError` for the first implausible value of ``z (B, K, D)`` (SI units).

    ``span``: per-column ``(min, max)`` the tracker was trained on, or None. ``where(b, k)``
    names sequence ``b``, scan ``k`` in the user's terms (file and row). NaN (missing) cells are
    left to the tracker's NaN policy.
    """
    z = torch.as_tensor(z, dtype=torch.float64)
    if z.ndim == 2:
        z = z[None]
    baselines = geometry.baselines_m()
    bad = torch.zeros(z.shape, dtype=torch.bool)
    reason = [""] * z.shape[-1]
    for d, label in enumerate(columns):
        kind, pair = _kind(label)
        v = z[..., d]
        if kind == "range" and pair is not None and pair < len(baselines):
            bad[..., d] = v < baselines[pair] - RANGE_SLACK_M
            reason[d] = f"a bistatic range below the pair's baseline of {baselines[pair]:.0f} m (impossible)"
        elif kind == "azimuth":
            bad[..., d] = v.abs() > math.pi + AZIMUTH_SLACK_RAD
            reason[d] = "an azimuth outside [-pi, pi] rad (degrees?)"
    inf = torch.isinf(z)
    if inf.any():
        b, k, d = (int(i) for i in inf.nonzero()[0])
        raise MeasurementError(f"{where(b, k)}: {columns[d]} is infinite (not a measurement; a missing scan is NaN)")
    far = torch.zeros_like(bad)
    if span is not None:
        lo, hi = (torch.as_tensor(v, dtype=torch.float64) for v in span)
        width = (hi - lo).clamp_min(1e-9)
        far = (z < lo - SPAN_FACTOR * width) | (z > hi + SPAN_FACTOR * width)
    nan = torch.isnan(z)
    bad, far = bad & ~nan, far & ~nan
    if (bad | far).any():
        b, k, d = (int(i) for i in (bad | far).nonzero()[0])
        if not bad[b, k, d]:
            reason[d] = (f"far outside what the tracker was trained on ({lo[d].item():.4g} to {hi[d].item():.4g}; "
                         "wrong units?)")
        raise MeasurementError(f"{where(b, k)}: {columns[d]} = {z[b, k, d].item():.6g} is {reason[d]}; "
                               "pass --force to track it anyway")
