"""Fixed true trajectories from a :class:`~.case_spec.CaseSpec`: start, speed, heading, and
segments of along-track / cross-track acceleration (the kinematics of
:mod:`pmsr_nn.simulation.flight`, shared with the simulator's manoeuvring tracks).

The acceleration a segment asks for is reached through a linear ramp of ``ramp_s`` seconds
from the previous segment's value (a jerk-limited manoeuvre onset rather than a step, which no
CA tracker with a small q could follow). The flight is integrated with a fine sub-step and
sampled every ``dt_s`` as a CA state ``[x, vx, ax, y, vy, ay]`` (the acceleration is the true
one at the sample time, turning with the velocity in a turn).
"""

from __future__ import annotations

import functools
import math

import torch

from ...errors import ConfigError
from ...motion import ConstantAcceleration
from ...simulation.flight import ca_sample, flight_substep
from ...simulation.recipe import TrackRecipe
from ...simulation.tracks import build_models, envelope_violations
from .case_spec import CaseSpec, SegmentSpec

SUBSTEPS = 100
"""Integration sub-steps per sampling interval (semi-implicit; error far below a millimetre)."""


def commanded_acceleration(segments: tuple[SegmentSpec, ...], t: float, ramp_s: float) -> tuple[float, float]:
    """(along, across) acceleration (m/s^2) the ``segments`` ask for at time ``t`` (s)."""
    start, prev = 0.0, (0.0, 0.0)
    for i, seg in enumerate(segments):
        target = (seg.along_mps2, seg.across_mps2)
        if i == 0:
            prev = target  # the flight starts already in its first segment
        end = start + seg.duration_s
        if t < end or i == len(segments) - 1:
            w = 1.0 if ramp_s <= 0 else min(1.0, max(0.0, (t - start) / ramp_s))
            return tuple(p + w * (c - p) for p, c in zip(prev, target))
        start, prev = end, target
    raise AssertionError("unreachable")


def design_trajectory(case: CaseSpec, recipe: TrackRecipe, ramp_s: float) -> torch.Tensor:
    """True states ``(K, 6)`` (float64, SI) sampled every ``recipe.motion.dt_s`` over the case's
    duration, ``K = duration / dt`` (rounded down, at least one sample)."""
    if recipe.dim != 2:
        raise ConfigError("designed trajectories are planar; use a 2-D recipe")
    dt = recipe.motion.dt_s
    K = int(math.floor(case.duration_s / dt + 1e-9))
    if K < 2:
        raise ConfigError(f"case {case.name!r}: the trajectory is empty ({case.duration_s} s at dt = {dt} s)")
    if getattr(case, "start_m", None) is not None:
        (x, y), (vx, vy) = case.start_m, case.velocity_mps
        if all(seg.along_mps2 == 0 and seg.across_mps2 == 0 for seg in case.segments):
            return straight_flight(x, y, vx, vy, K, dt)
        v, psi = math.hypot(vx, vy), math.atan2(vx, vy)
    else:
        ox, oy = recipe.geometry.transmitters[0].position_m[:2]
        b = math.radians(case.start_bearing_deg)
        x, y = ox + case.start_range_m * math.sin(b), oy + case.start_range_m * math.cos(b)
        psi = math.radians(case.heading_deg)
        v = case.speed_mps
    return _flown(tuple(case.segments), float(x), float(y), float(v), float(psi), K, float(dt), float(ramp_s)).clone()


@functools.lru_cache(maxsize=256)
def _flown(segments: tuple[SegmentSpec, ...], x: float, y: float, v: float, psi: float, K: int, dt: float,
           ramp_s: float) -> torch.Tensor:
    """The integrated flight ``(K, 6)``, kept per process: a scenario prepared again (a merge after
    its evaluation, each shard or bank block, the tests) does not integrate its flights again,
    ``SUBSTEPS`` scalar sub-steps per sample. Callers get a clone."""
    h = dt / SUBSTEPS
    out = []
    t = 0.0
    for k in range(K):
        for s in range(SUBSTEPS if k else 0):
            along, across = commanded_acceleration(segments, t, ramp_s)
            x, y, v, psi = flight_substep(x, y, v, psi, along, across, h)
            t += h
        t = k * dt  # no drift of the clock over many sub-steps
        along, across = commanded_acceleration(segments, t, ramp_s)
        out.append(ca_sample(x, y, v, psi, along, across))
    return torch.tensor(out, dtype=torch.float64)


def straight_flight(x: float, y: float, vx: float, vy: float, K: int, dt: float) -> torch.Tensor:
    """CA states ``(K, 6)`` of a straight, unaccelerated flight from ``(x, y)`` at ``(vx, vy)``,
    in closed form: position ``start + (k dt) v`` at sample ``k`` (no integration error)."""
    t = torch.arange(K, dtype=torch.float64) * dt
    zero = torch.zeros_like(t)
    return torch.stack([x + t * vx, torch.full_like(t, vx), zero, y + t * vy, torch.full_like(t, vy), zero], -1)


def check_inside(truth: torch.Tensor, recipe: TrackRecipe, name: str) -> None:
    """A :class:`ConfigError` if the trajectory leaves the recipe's envelope (where the learned
    trackers were trained) or passes within ``min_sensor_distance_m`` of a sensor."""
    motion = ConstantAcceleration(spatial_dim=recipe.dim)
    bad = {k: bool(v[0]) for k, v in envelope_violations(recipe, truth[None], motion).items()}
    left = [k for k, v in bad.items() if v]
    if left:
        env = recipe.envelope
        raise ConfigError(f"case {name!r} leaves the recipe's envelope ({', '.join(left)}; range {env.range_m} m, "
                          f"speed {env.speed_mps} m/s, azimuth {env.azimuth_deg} deg from the transmitter)")
    _, model = build_models(recipe)
    near = model.near_sensor(truth, recipe.min_sensor_distance_m)
    if bool(near.any()):
        k = int(near.nonzero()[0])
        raise ConfigError(f"case {name!r} passes within {recipe.min_sensor_distance_m} m of a sensor at step {k}")
