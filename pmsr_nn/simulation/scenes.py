"""Multi-target scenes drawn on the fly: training data for trackers that read detections.

A scene is ``N`` targets over ``K`` scans, every target alive throughout. Target 0 is a track
of the recipe (:func:`~.tracks.generate_tracks`: its envelope, motion model and interval);
every other target is, independently, with probabilities ``formation`` / ``crossing`` / the rest:

* a **formation mate** of target 0: the same flight shifted by ``offset_m`` (uniform length,
  uniform direction), so the two stay that far apart (close in azimuth, often in range);
* a **crossing** target: target 0's flight rotated by a uniform angle of ``crossing_deg`` about
  its position at a uniform scan of the middle half of the window, so both are at the same point
  at that scan (their measurements coincide at every pair) and part again;
* an **independent** track of the recipe.

A formation or crossing target that would pass within ``min_sensor_distance_m`` of a sensor is
replaced by its independent track. Draws come only from the generator: the same seed gives the
same scenes.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from ..config import check_interval, require
from ..geometry import Geometry
from .recipe import TrackRecipe
from .tracks import generate_tracks


def _rotate(v: torch.Tensor, c: torch.Tensor, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotation of 2-D vectors ``v (..., 2)`` (east, north) by angles with cosines ``c`` and sines ``s``."""
    return c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]


def draw_scenes(recipe: TrackRecipe, geometry: Geometry, B: int, N: int, K: int, g: torch.Generator,
                formation: float = 0.35, crossing: float = 0.35, offset_m: tuple[float, float] = (100.0, 500.0),
                crossing_deg: tuple[float, float] = (20.0, 160.0)) -> torch.Tensor:
    """Truth ``(B, K, N, n)`` (SI, the recipe's CA state layout) of ``B`` scenes (module docstring)."""
    require(B >= 1 and N >= 1 and K >= 2, f"scenes need B >= 1, N >= 1, K >= 2; got {B}, {N}, {K}")
    require(recipe.dim == 2, "scenes are drawn for planar recipes (dim 2)")
    require(formation >= 0 and crossing >= 0 and formation + crossing <= 1,
            f"formation ({formation}) and crossing ({crossing}) are probabilities that sum to at most 1")
    check_interval("offset_m", offset_m, nonneg=True)
    check_interval("crossing_deg", crossing_deg)
    short = recipe.with_overrides(motion=replace(recipe.motion, steps=K), window=K)
    tracks, _ = generate_tracks(short, B * N, g)
    x = tracks.states.reshape(B, N, K, -1).transpose(1, 2).clone()  # (B, K, N, n)
    lead = x[:, :, :1]
    u = torch.rand(B, N, generator=g, dtype=torch.float64)
    # formation: shift the lead's positions (state entries 0 and 3: east, north)
    length = offset_m[0] + (offset_m[1] - offset_m[0]) * torch.rand(B, N, generator=g, dtype=torch.float64)
    angle = 2 * math.pi * torch.rand(B, N, generator=g, dtype=torch.float64)
    mate = lead.expand(-1, -1, N, -1).clone()
    mate[..., 0] += (length * torch.sin(angle))[:, None]
    mate[..., 3] += (length * torch.cos(angle))[:, None]
    # crossing: rotate the lead's flight about its position at the meeting scan
    theta = torch.deg2rad(crossing_deg[0] + (crossing_deg[1] - crossing_deg[0])
                          * torch.rand(B, N, generator=g, dtype=torch.float64))
    theta = theta * torch.where(torch.rand(B, N, generator=g) < 0.5, -1.0, 1.0).to(theta.dtype)
    meet = torch.randint(K // 4, max(K // 4 + 1, 3 * K // 4), (B,), generator=g)
    centre = lead[torch.arange(B), meet, 0][:, None, None, :]  # (B, 1, 1, n)
    c, s = torch.cos(theta)[:, None], torch.sin(theta)[:, None]
    cross = lead.expand(-1, -1, N, -1).clone()
    for i in range(3):  # position (about the meeting point), velocity, acceleration
        east, north = i, 3 + i
        base = centre[..., [east, north]] if i == 0 else 0.0
        v = lead[..., [east, north]] - base
        re, rn = _rotate(v, c, s)
        cross[..., east] = re + (centre[..., east] if i == 0 else 0.0)
        cross[..., north] = rn + (centre[..., north] if i == 0 else 0.0)
    kind = torch.where(u < formation, 1, torch.where(u < formation + crossing, 2, 0))
    kind[:, 0] = 0
    out = torch.where((kind == 1)[:, None, :, None], mate, torch.where((kind == 2)[:, None, :, None], cross, x))
    sensors = torch.cat([geometry.pair_tx_positions(torch.float64), geometry.pair_rx_positions(torch.float64)])
    dist = (out[..., None, [0, 3]] - sensors).norm(dim=-1).amin(-1).amin(1)  # (B, N)
    near = dist < recipe.min_sensor_distance_m
    return torch.where(near[:, None, :, None], x, out)
