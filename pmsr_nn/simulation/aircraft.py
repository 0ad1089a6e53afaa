"""Designed aircraft flights in 3-D: legs of along-track / cross-track acceleration and climb
rate, integrated with the kinematics of :mod:`.flight`, sampled as CV states.

An aircraft is seen (``alive``) while its legs last, from its ``birth_s``, above a minimum
altitude and inside a maximum bistatic range: the Daniyan seed's receiver kept detections above
100 m and had a maximum detection range of about 48 km, so an aircraft taking off appears when
it climbs through 100 m and one landing disappears when it descends below it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import require
from ..errors import ConfigError
from .flight import flight_substep

SUBSTEPS = 20
"""Integration sub-steps per sampling interval."""


@dataclass(frozen=True)
class LegSpec:
    """A stretch of ``duration_s`` with constant along-track and cross-track accelerations (m/s^2;
    ``across > 0`` turns right) and climb rate ``climb_mps`` (m/s, negative descends)."""

    duration_s: float
    along_mps2: float = 0.0
    across_mps2: float = 0.0
    climb_mps: float = 0.0

    def __post_init__(self) -> None:
        require(self.duration_s > 0 and all(math.isfinite(v) for v in (self.duration_s, self.along_mps2,
                                                                        self.across_mps2, self.climb_mps)),
                f"a leg needs a positive duration_s and finite rates, got {self}")


@dataclass(frozen=True)
class AircraftSpec:
    """One aircraft: ``start_m`` (x east, y north, m) and ``altitude_m`` at ``birth_s`` (s from the
    scenario's start), speed and heading (deg clockwise from north), then its legs."""

    name: str
    start_m: tuple[float, float]
    altitude_m: float
    speed_mps: float
    heading_deg: float
    legs: tuple[LegSpec, ...]
    birth_s: float = 0.0

    def __post_init__(self) -> None:
        require(bool(self.name), "an aircraft needs a name")
        require(len(self.start_m) == 2 and all(math.isfinite(v) for v in self.start_m),
                f"aircraft {self.name!r}: start_m must be a finite [x, y], got {list(self.start_m)}")
        require(self.altitude_m >= 0 and self.speed_mps >= 0 and self.birth_s >= 0,
                f"aircraft {self.name!r}: altitude_m, speed_mps and birth_s must be >= 0")
        require(len(self.legs) > 0, f"aircraft {self.name!r} has no legs")

    @property
    def end_s(self) -> float:
        return self.birth_s + sum(leg.duration_s for leg in self.legs)


def _leg_at(legs: tuple[LegSpec, ...], t: float) -> LegSpec:
    for leg in legs:
        if t < leg.duration_s:
            return leg
        t -= leg.duration_s
    return legs[-1]


def fly(spec: AircraftSpec, K: int, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """States ``(K, 6)`` ``[x, vx, y, vy, z, vz]`` at scans ``k dt`` (NaN outside the legs) and
    ``flying (K,)``: the scans within the aircraft's legs."""
    x = torch.full((K, 6), float("nan"), dtype=torch.float64)
    flying = torch.zeros(K, dtype=torch.bool)
    px, py, pz = float(spec.start_m[0]), float(spec.start_m[1]), float(spec.altitude_m)
    v, psi = float(spec.speed_mps), math.radians(spec.heading_deg)
    t, h = 0.0, dt / SUBSTEPS  # time since birth
    for k in range(K):
        tk = k * dt - spec.birth_s
        if tk < -1e-9 or tk > spec.end_s - spec.birth_s + 1e-9:
            continue
        while t < tk - 1e-9:
            step = min(h, tk - t)
            leg = _leg_at(spec.legs, t)
            px, py, v, psi = flight_substep(px, py, v, psi, leg.along_mps2, leg.across_mps2, step)
            pz += leg.climb_mps * step
            t += step
        climb = _leg_at(spec.legs, t).climb_mps
        x[k] = torch.tensor([px, v * math.sin(psi), py, v * math.cos(psi), pz, climb], dtype=torch.float64)
        flying[k] = True
    return x, flying


def fly_all(aircraft: tuple[AircraftSpec, ...], K: int, dt: float, model, min_altitude_m: float,
            max_range_m: float, min_sensor_distance_m: float = 1000.0) -> tuple[torch.Tensor, torch.Tensor]:
    """States ``(K, N, 6)`` (NaN where not seen) and ``alive (K, N)`` of every aircraft, seen above
    ``min_altitude_m`` and within ``max_range_m`` of bistatic range (of the first pair of
    ``model``). A seen aircraft within ``min_sensor_distance_m`` of a sensor is refused."""
    xs, alive = [], []
    for a in aircraft:
        x, flying = fly(a, K, dt)
        seen = flying & (x[:, 4] >= min_altitude_m)
        r = model.h(torch.nan_to_num(x))[:, 0]
        seen &= r <= max_range_m
        near = model.near_sensor(torch.nan_to_num(x), min_sensor_distance_m) & seen
        if bool(near.any()):
            raise ConfigError(f"aircraft {a.name!r} passes within {min_sensor_distance_m:g} m of a sensor at "
                              f"{int(near.nonzero()[0]) * dt:g} s")
        if not bool(seen.any()):
            raise ConfigError(f"aircraft {a.name!r} is never seen (above {min_altitude_m:g} m and within "
                              f"{max_range_m:g} m of bistatic range)")
        xs.append(torch.where(seen[:, None], x, torch.full((), float("nan"), dtype=torch.float64)))
        alive.append(seen)
    return torch.stack(xs, 1), torch.stack(alive, 1)
