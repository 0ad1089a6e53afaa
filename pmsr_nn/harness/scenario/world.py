"""A scenario's own world (schema): sensors, constant-velocity motion and track initiation given
in the scenario instead of a recipe, and the targets a case flies in it.

Takes plain YAML data (through :func:`~pmsr_nn.config.from_dict`); gives frozen, checked specs:
:class:`WorldSpec` (the scenario's ``world`` section: ``scans`` of ``motion.dt_s``, the
transmitters and receivers, CV motion of truth and trackers, the initiation prior, what the
sensors see of designed aircraft) and a case's targets in it, a :class:`FormationSpec` or listed
:class:`TargetStateSpec` (designed aircraft are :class:`~pmsr_nn.simulation.aircraft.AircraftSpec`).
This is the S-MSJPDA paper's simulation (a formation flying CV with process noise, range and
Doppler from every transmitter-receiver pair, tracks started at the truth plus noise) and the
other multi-target studies'. Distances in m, speeds in m/s, ``dt_s`` in s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch

from ...config import require
from ...simulation.recipe import GeometrySpec


@dataclass(frozen=True)
class FormationSpec:
    """``count`` targets side by side, ``spacing_m`` apart across the common velocity
    ``velocity_mps`` (east, north), the formation's centre at ``centre_m`` at the first scan."""

    count: int = 4
    centre_m: tuple[float, float] = (-25_000.0, -20_000.0)
    velocity_mps: tuple[float, float] = (200.0, 244.1)
    spacing_m: float = 2000.0

    def __post_init__(self) -> None:
        require(self.count >= 1, f"formation.count must be at least 1, got {self.count}")
        require(self.spacing_m >= 0, f"formation.spacing_m must be >= 0, got {self.spacing_m}")

    def initial_states(self) -> torch.Tensor:
        """CV states ``(count, 4)`` ``[x, vx, y, vy]`` at the first scan."""
        v = torch.tensor(self.velocity_mps, dtype=torch.float64)
        speed = float(v.norm())
        across = torch.tensor([v[1], -v[0]], dtype=torch.float64) / max(speed, 1e-12)  # to the right of the track
        offsets = (torch.arange(self.count, dtype=torch.float64) - (self.count - 1) / 2) * self.spacing_m
        pos = torch.tensor(self.centre_m, dtype=torch.float64) + offsets[:, None] * across
        return torch.stack([pos[:, 0], v[0].expand(self.count), pos[:, 1], v[1].expand(self.count)], dim=-1)


@dataclass(frozen=True)
class TargetStateSpec:
    """One target's state at the first scan: ``position_m`` and ``velocity_mps`` ([x, y] or
    [x, y, z], the world's ``dimensions``)."""

    position_m: tuple[float, ...]
    velocity_mps: tuple[float, ...]

    def __post_init__(self) -> None:
        require(len(self.position_m) == len(self.velocity_mps) and len(self.position_m) in (2, 3)
                and all(math.isfinite(v) for v in (*self.position_m, *self.velocity_mps)),
                f"a target's position_m and velocity_mps must be finite [x, y] or [x, y, z], got "
                f"{list(self.position_m)} / {list(self.velocity_mps)}")

    def state(self) -> list[float]:
        """Axis-major CV state ``[x, vx, y, vy(, z, vz)]``."""
        return [v for p, u in zip(self.position_m, self.velocity_mps) for v in (p, u)]


@dataclass(frozen=True)
class CVMotionSpec:
    """CV motion of truth and trackers: interval ``dt_s``; ``model`` ``cv`` (discrete white
    acceleration, ``q`` its variance in m^2/s^4) or ``cv_continuous`` (continuous white
    acceleration, ``q`` its PSD in m^2/s^3); ``vertical_q``: the vertical axis's q in 3-D
    (default: ``q``). ``truth``: ``sampled`` (each run's flights drawn with that process noise) or
    ``straight`` (every run flies the same straight lines; the trackers still assume ``q``)."""

    dt_s: float = 1.0
    q: float = 1.0
    model: Literal["cv", "cv_continuous"] = "cv"
    vertical_q: float | None = None
    truth: Literal["sampled", "straight"] = "sampled"

    def __post_init__(self) -> None:
        require(self.dt_s > 0 and self.q >= 0, "motion: dt_s must be positive and q non-negative")
        require(self.vertical_q is None or self.vertical_q >= 0, "motion: vertical_q must be non-negative")

    def q_per_axis(self, dims: int):
        """``q`` as the trackers use it: a float, or a per-axis tensor when the vertical one differs."""
        if dims == 2 or self.vertical_q is None or self.vertical_q == self.q:
            return self.q
        return torch.tensor([self.q, self.q, self.vertical_q], dtype=torch.float64)


@dataclass(frozen=True)
class PriorSpec:
    """Track initiation: truth plus a draw from ``N(0, P0)``, ``P0`` from these deviations (in 3-D
    ``altitude_m`` and ``vertical_mps`` for the vertical axis; default the horizontal ones)."""

    position_m: float = 500.0
    velocity_mps: float = 20.0
    altitude_m: float | None = None
    vertical_mps: float | None = None

    def __post_init__(self) -> None:
        require(self.position_m > 0 and self.velocity_mps > 0, "prior deviations must be positive")
        require((self.altitude_m is None or self.altitude_m > 0) and (self.vertical_mps is None or self.vertical_mps > 0),
                "prior deviations must be positive")

    def sd(self, dims: int = 2) -> torch.Tensor:
        """Deviations ``(2 * dims,)`` of the axis-major CV state."""
        sd = [self.position_m, self.velocity_mps] * 2
        if dims == 3:
            sd += [self.altitude_m or self.position_m, self.vertical_mps or self.velocity_mps]
        return torch.tensor(sd, dtype=torch.float64)


@dataclass(frozen=True)
class WorldSpec:
    """The scenario's own world: ``scans`` scans of ``motion.dt_s``, the sensors ``geometry``
    (``dimensions`` 2 or 3), CV ``motion`` of truth and trackers, the initiation ``prior`` (a case
    may override it), and what the sensors see of designed aircraft: above ``min_altitude_m`` and
    within ``max_range_m`` of bistatic range (None: no limit)."""

    scans: int
    geometry: GeometrySpec
    dimensions: int = 2
    motion: CVMotionSpec = CVMotionSpec()
    prior: PriorSpec = PriorSpec()
    min_altitude_m: float = 100.0
    max_range_m: float | None = None

    def __post_init__(self) -> None:
        require(2 <= self.scans <= 100_000, f"world.scans must be in [2, 100000], got {self.scans}")
        require(self.dimensions in (2, 3), f"world.dimensions must be 2 or 3, got {self.dimensions}")
        require(self.max_range_m is None or self.max_range_m > 0,
                f"world.max_range_m must be positive, got {self.max_range_m}")
        require(math.isfinite(self.min_altitude_m), f"world.min_altitude_m must be finite, got {self.min_altitude_m}")
