"""Detections with missed targets and clutter, per sensor and scan, for multi-target trackers.

A *sensor* is a transmitter-receiver pair (the S-MSJPDA paper's word). At every scan each target
is detected by each sensor with probability ``pd`` (independently), its measurement being the
noise-free ``h(x)`` plus Gaussian noise; each sensor also reports clutter points uniform over its
measurement box (a fixed number per scan, as in the paper's simulations, or a Poisson number).

Detections of a scan and sensor are stored padded, in random order (a tracker can not learn
anything from the position of a detection in the list), with the truth origin of each kept for
evaluation: a target index, :data:`CLUTTER` or :data:`PADDING`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch

from ..config import check_interval, require
from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..rng import standard_normal

CLUTTER = -1
PADDING = -2


@dataclass(frozen=True)
class ClutterSpec:
    """Clutter of one sensor and scan: ``per_scan`` points (the exact number for ``model="fixed"``,
    the Poisson mean for ``"poisson"``), uniform over a box of the sensor's measurement space, the
    same box for every sensor: bistatic range ``range_m`` (m) and, for the components the model
    has, Doppler ``doppler_hz`` (Hz), bistatic range-rate ``range_rate_mps`` (m/s) and azimuth
    ``azimuth_deg`` (deg)."""

    per_scan: float = 50.0
    model: Literal["fixed", "poisson"] = "fixed"
    range_m: tuple[float, float] = (0.0, 150_000.0)
    doppler_hz: tuple[float, float] = (-250.0, 250.0)
    range_rate_mps: tuple[float, float] = (-300.0, 300.0)
    azimuth_deg: tuple[float, float] = (-180.0, 180.0)

    def __post_init__(self) -> None:
        require(self.per_scan >= 0 and math.isfinite(self.per_scan), f"clutter per_scan must be >= 0, got {self.per_scan}")
        require(self.model == "poisson" or float(self.per_scan).is_integer(),
                f"a fixed clutter count must be a whole number, got {self.per_scan}")
        check_interval("clutter range_m", self.range_m, nonneg=True)
        check_interval("clutter doppler_hz", self.doppler_hz)
        check_interval("clutter range_rate_mps", self.range_rate_mps)
        check_interval("clutter azimuth_deg", self.azimuth_deg)
        require(-180.0 <= self.azimuth_deg[0] and self.azimuth_deg[1] <= 180.0,
                f"clutter azimuth_deg must lie in [-180, 180], got {self.azimuth_deg}")
        require(self.volume > 0, "the clutter box must have a positive area")

    def box(self, components=("range", "doppler")) -> tuple[list[float], list[float]]:
        """Lower corner and extent of the box over ``components``, in SI units (azimuth in rad)."""
        bounds = {"range": self.range_m, "doppler": self.doppler_hz, "range_rate": self.range_rate_mps,
                  "azimuth": tuple(math.radians(a) for a in self.azimuth_deg)}
        lo = [float(bounds[c][0]) for c in components]
        return lo, [float(bounds[c][1]) - v for c, v in zip(components, lo)]

    def volume_of(self, components=("range", "doppler")) -> float:
        """Volume of the measurement box over ``components`` (SI units, azimuth in rad)."""
        return math.prod(self.box(components)[1])

    def density_of(self, components=("range", "doppler")) -> float:
        """Expected clutter points per unit of that measurement space."""
        return self.per_scan / self.volume_of(components)

    @property
    def volume(self) -> float:
        """Area of the range x Doppler box (m Hz): the paper's ``V_s``."""
        return self.volume_of()

    @property
    def density(self) -> float:
        """Expected clutter points per unit of range x Doppler (1 / (m Hz))."""
        return self.density_of()


def pad_axis(t: torch.Tensor, size: int, fill, dim: int) -> torch.Tensor:
    """``t`` with its axis ``dim`` padded to ``size`` with ``fill`` (as it is where already that long)."""
    extra = size - t.shape[dim]
    if extra <= 0:
        return t
    shape = list(t.shape)
    shape[dim] = extra
    return torch.cat([t, t.new_full(shape, fill)], dim)


@dataclass
class Scans:
    """Detections of ``B`` runs over ``K`` scans from ``S`` sensors (pairs), padded to ``M`` per list.

    ``z (B, K, S, M, m)`` measurements in the sensor's units (NaN where padded), ``valid (B, K, S, M)``,
    ``origin (B, K, S, M)`` int64: index of the target that caused it, :data:`CLUTTER` or
    :data:`PADDING`. Valid detections come first in each list.
    """

    z: torch.Tensor
    valid: torch.Tensor
    origin: torch.Tensor

    @property
    def shape(self) -> tuple[int, int, int, int]:
        B, K, S, M = self.valid.shape
        return B, K, S, M

    @classmethod
    def concat(cls, parts: list["Scans"]) -> "Scans":
        """The runs of ``parts`` one after another, each padded to the longest list ``M`` (padding
        is invalid, NaN, origin :data:`PADDING`: a tracker reads only valid detections)."""
        M = max(p.shape[3] for p in parts)
        return cls(torch.cat([pad_axis(p.z, M, math.nan, 3) for p in parts]),
                   torch.cat([pad_axis(p.valid, M, False, 3) for p in parts]),
                   torch.cat([pad_axis(p.origin, M, PADDING, 3) for p in parts]))

    def to(self, device: torch.device | str) -> "Scans":
        """The same detections on ``device``."""
        return Scans(self.z.to(device), self.valid.to(device), self.origin.to(device))

    def target_measurements(self, n_targets: int) -> torch.Tensor:
        """The detection each target caused, ``(B, K, N, S, m)`` (NaN where missed): what a tracker
        that knew the true assignment would use."""
        B, K, S, M = self.shape
        m = self.z.shape[-1]
        out = self.z.new_full((B, K, n_targets, S, m), float("nan"))
        b, k, s, i = torch.nonzero(self.origin >= 0, as_tuple=True)
        out[b, k, self.origin[b, k, s, i], s] = self.z[b, k, s, i]
        return out


def check_model_for_detections(model: MeasurementModel) -> None:
    """Detections are per sensor, bistatic range first (the loss rule reads its deviation)."""
    if model.layout != "pair" or model.components[0] != "range":
        raise ConfigError("detections are per sensor with the bistatic range first: the measurement model needs "
                          f"layout 'pair' and components starting with 'range', got {model.components} / {model.layout!r}")


def simulate_scans(truth: torch.Tensor, model: MeasurementModel, pd: float, clutter: ClutterSpec,
                   generator: torch.Generator | None = None, alive: torch.Tensor | None = None) -> Scans:
    """Detections of targets ``truth (B, K, N, n)`` (SI states) by every sensor of ``model``;
    ``alive (K, N)`` or ``(B, K, N)`` (default: all) says which targets exist at each scan (a
    target that does not is never detected; its states may be NaN).

    All draws for all runs at once, from ``generator``: detection (``pd``), measurement noise
    (``model.noise_std``), clutter count and positions, and the shuffle of each list. Angles
    (azimuth) are wrapped to (-pi, pi].
    """
    from ..measurements import wrap_angle

    check_model_for_detections(model)
    require(0.0 <= pd <= 1.0, f"pd must be in [0, 1], got {pd}")
    if truth.dim() != 4:
        raise ConfigError(f"truth must be (runs, scans, targets, state), got shape {tuple(truth.shape)}")
    B, K, N, _ = truth.shape
    S, m = model.n_pairs, len(model.components)
    dtype, device = truth.dtype, truth.device
    clean = model.h(truth).reshape(B, K, N, S, m)
    noisy = clean + standard_normal(clean.shape, generator, dtype, device) * torch.tensor(model.noise_std, dtype=dtype, device=device)
    if "azimuth" in model.components:
        angles = torch.tensor([c == "azimuth" for c in model.components], device=device)
        noisy = torch.where(angles, wrap_angle(noisy), noisy)
    detected = torch.rand((B, K, N, S), generator=generator, dtype=dtype, device=device) < pd
    if alive is not None:
        detected = detected & alive.to(device).expand(B, K, N).unsqueeze(-1)
    target_z = noisy.permute(0, 1, 3, 2, 4)  # (B, K, S, N, m)
    target_ok = detected.permute(0, 1, 3, 2)

    if clutter.model == "fixed":
        counts = torch.full((B, K, S), int(clutter.per_scan), dtype=torch.int64, device=device)
    else:
        rate = torch.full((B, K, S), float(clutter.per_scan), dtype=dtype, device=device)
        counts = torch.poisson(rate, generator=generator).to(torch.int64)
    C = int(counts.max()) if counts.numel() else 0
    lo, span = (torch.tensor(v, dtype=dtype, device=device) for v in clutter.box(model.components))
    clutter_z = lo + span * torch.rand((B, K, S, C, m), generator=generator, dtype=dtype, device=device)
    clutter_ok = torch.arange(C, device=device) < counts.unsqueeze(-1)

    z = torch.cat([target_z, clutter_z], dim=3)
    valid = torch.cat([target_ok, clutter_ok], dim=3)
    target_ids = torch.arange(N, device=device).expand(B, K, S, N)
    origin = torch.cat([target_ids, torch.full((B, K, S, C), CLUTTER, dtype=torch.int64, device=device)], dim=3)
    z, valid, (origin,) = shuffled(z, valid, (origin,), generator)
    return Scans(z, valid, origin.masked_fill(~valid, PADDING))


def shuffled(z: torch.Tensor, valid: torch.Tensor, labels: tuple[torch.Tensor, ...], generator: torch.Generator | None):
    """Lists ``z (..., M, d)``, ``valid (..., M)`` and per-detection ``labels`` in a random order
    of the valid detections, padding last, cut to the longest list: one draw per slot."""
    keys = torch.rand(valid.shape, generator=generator, dtype=z.dtype, device=z.device).masked_fill(~valid, 2.0)
    order = keys.argsort(dim=-1)
    M = int(valid.sum(-1).max()) if valid.numel() else 0
    order = order[..., :M]
    valid = valid.gather(-1, order)
    z = z.gather(-2, order.unsqueeze(-1).expand(*order.shape, z.shape[-1])).masked_fill(~valid.unsqueeze(-1), float("nan"))
    return z, valid, tuple(lab.gather(-1, order) for lab in labels)


@dataclass
class PooledScans:
    """Detections pooled per receiver, as a single-frequency network (SFN) receiver sees them: it
    can not tell which transmitter's signal a detection came from.

    ``scans``: ``L`` lists per scan, one per receiver (``z (B, K, L, M, d)``, origin a target index,
    :data:`CLUTTER` or :data:`PADDING`); ``pair (B, K, L, M)``: truth only, the transmitter-receiver
    pair whose list the detection was drawn in (a target detection's illuminator; for clutter, the
    pair it was drawn for; -1 for padding); ``routes (L, S)``: pair ``s`` ends at receiver ``l``.
    """

    scans: Scans
    pair: torch.Tensor
    routes: torch.Tensor

    @classmethod
    def concat(cls, parts: list["PooledScans"]) -> "PooledScans":
        """The runs of ``parts`` one after another (:meth:`Scans.concat`; the same network's routes)."""
        M = max(p.scans.shape[3] for p in parts)
        return cls(Scans.concat([p.scans for p in parts]), torch.cat([pad_axis(p.pair, M, -1, 3) for p in parts]),
                   parts[0].routes)

    def to(self, device: torch.device | str) -> "PooledScans":
        """The same lists on ``device``."""
        return PooledScans(self.scans.to(device), self.pair.to(device), self.routes.to(device))


def receiver_routes(model: MeasurementModel) -> torch.Tensor:
    """``(L, S)`` bool: pair ``s`` of ``model`` ends at receiver ``l``."""
    rx = torch.tensor([j for _, j in model.geometry.pairs])
    return torch.arange(len(model.geometry.receivers))[:, None] == rx


def pool_by_receiver(scans: Scans, model: MeasurementModel, generator: torch.Generator | None = None) -> PooledScans:
    """Each receiver's pairs' lists ``scans (B, K, S, M, d)`` joined into one list per receiver,
    shuffled again (from ``generator``) so a detection's place says nothing about its pair."""
    routes = receiver_routes(model)
    B, K, S, M = scans.shape
    if S != routes.shape[1]:
        raise ConfigError(f"detections are from {S} sensors; the model has {routes.shape[1]}")
    pair_id = torch.arange(S, device=scans.z.device)[:, None].expand(B, K, S, M).masked_fill(~scans.valid, -1)
    lists = [[t[:, :, routes[l]].flatten(2, 3) for t in (scans.z, scans.valid, scans.origin, pair_id)]
             for l in range(routes.shape[0])]
    width = max(v.shape[2] for _, v, _, _ in lists)

    def stack(i: int, fill) -> torch.Tensor:
        parts = []
        for part in lists:
            t = part[i]
            pad = list(t.shape)
            pad[2] = width - t.shape[2]
            parts.append(torch.cat([t, t.new_full(pad, fill)], 2))
        return torch.stack(parts, 2)

    z, valid = stack(0, float("nan")), stack(1, False)
    z, valid, (origin, pair) = shuffled(z, valid, (stack(2, PADDING), stack(3, -1)), generator)
    return PooledScans(Scans(z, valid, origin.masked_fill(~valid, PADDING)), pair.masked_fill(~valid, -1), routes)
