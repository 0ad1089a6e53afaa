"""The constant-acceleration track generator of Section 2 of the MDFNN paper, batched.

A chunk of tracks is drawn at once: initial states by polar decomposition (Eqs. 7-9), CA
trajectories with the process noise of Eq. 12, per-track noise deviations and noisy
``[r_1..r_N, rdot_1..rdot_N, phi_1..phi_N]`` measurements (Eq. 6). Everything is float64 and
every draw comes from the ``torch.Generator`` passed in.

Two variants (``recipe.variant``):

* ``literal``: the recipe as written. Tracks are kept whatever they do; the fraction that leaves
  the Table 1 envelope is measured and reported.
* ``envelope``: the envelope-variant values replace the paper's jerk PSD, initial acceleration
  and initial bearing, and any track that leaves the envelope at any step is redrawn (rejection),
  so the motion model stays exactly CA with process noise ``Q`` (which the filters and the PCRB
  assume) while every kept track satisfies Table 1.

In both variants a track passing within ``min_sensor_distance_m`` of a sensor is redrawn: the
range-rate is undefined on top of a sensor (see :mod:`pmsr_nn.measurements`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..motion import ConstantAcceleration
from .recipe import TrackRecipe

MEASUREMENT_COMPONENTS = ("range", "range_rate", "azimuth")
ENVELOPE_CRITERIA = ("range", "speed", "azimuth")


def chunk_generator(seed: int, *stream: int) -> torch.Generator:
    """An independent generator for ``(seed, *stream)``, e.g. one per chunk of tracks."""
    state = np.random.SeedSequence([seed, *stream]).generate_state(2, np.uint32)
    g = torch.Generator()
    g.manual_seed(int(state[0]) << 32 | int(state[1]))
    return g


def build_models(recipe: TrackRecipe) -> tuple[ConstantAcceleration, MeasurementModel]:
    """The motion model and the measurement model (mid-interval noise as nominal ``R``)."""
    motion = ConstantAcceleration(spatial_dim=recipe.dim)
    nominal = tuple(0.5 * (lo + hi) for lo, hi in recipe.noise.intervals_si())
    meas = MeasurementModel(recipe.geometry.build(recipe.dim), MEASUREMENT_COMPONENTS, nominal, motion.pos_idx, motion.vel_idx)
    return motion, meas


def _uniform(lo_hi, n: int, g: torch.Generator) -> torch.Tensor:
    lo, hi = lo_hi
    return lo + (hi - lo) * torch.rand(n, generator=g, dtype=torch.float64)


def draw_initial_states(recipe: TrackRecipe, n: int, g: torch.Generator) -> torch.Tensor:
    """Initial CA states ``(n, dim_x)`` by polar decomposition (Eqs. 7-9), transmitter at the origin."""
    init = recipe.effective_motion().initial
    deg = math.pi / 180
    origin = torch.tensor(recipe.geometry.transmitters[0].position_m, dtype=torch.float64)
    r, th = _uniform(init.range_m, n, g), _uniform(init.bearing_deg, n, g) * deg
    v, tv = _uniform(init.speed_mps, n, g), _uniform(init.heading_deg, n, g) * deg
    a, ta = _uniform(init.accel_mps2, n, g), _uniform(init.accel_heading_deg, n, g) * deg
    axes = [
        [origin[0] + r * torch.sin(th), v * torch.sin(tv), a * torch.sin(ta)],  # east
        [origin[1] + r * torch.cos(th), v * torch.cos(tv), a * torch.cos(ta)],  # north
    ]
    if recipe.dim == 3:  # level flight at a drawn altitude above ground sensors
        zero = torch.zeros(n, dtype=torch.float64)
        axes.append([_uniform(init.altitude_m, n, g), zero, zero])
    return torch.stack([c for axis in axes for c in axis], dim=-1)


@dataclass
class TrackBatch:
    """A chunk of generated tracks.

    ``states (B, K, dim_x)`` in SI, ``measurements (B, K, dim_z)`` (m, m/s, rad) and the per-track
    noise deviations ``noise_std (B, 3)`` (m, m/s, rad); ``violations`` maps each envelope
    criterion to a boolean ``(B,)`` (the track leaves the envelope that way at some step).
    """

    states: torch.Tensor
    measurements: torch.Tensor
    noise_std: torch.Tensor
    violations: dict[str, torch.Tensor]

    @property
    def left_envelope(self) -> torch.Tensor:
        return torch.stack(list(self.violations.values())).any(0)


@dataclass
class DrawStats:
    """How many candidate tracks were drawn and why candidates were rejected."""

    drawn: int = 0
    rejected_envelope: int = 0
    rejected_near_sensor: int = 0
    by_criterion: dict[str, int] = field(default_factory=lambda: dict.fromkeys(ENVELOPE_CRITERIA, 0))

    def add(self, other: "DrawStats") -> None:
        self.drawn += other.drawn
        self.rejected_envelope += other.rejected_envelope
        self.rejected_near_sensor += other.rejected_near_sensor
        for k, v in other.by_criterion.items():
            self.by_criterion[k] += v


def envelope_violations(recipe: TrackRecipe, states: torch.Tensor, motion: ConstantAcceleration) -> dict[str, torch.Tensor]:
    """Per track ``(B,)``: does it leave the Table 1 range / speed / azimuth envelope at any step?

    Distance and azimuth are horizontal, from the first transmitter; azimuth clockwise from north.
    """
    env = recipe.envelope
    origin = torch.tensor(recipe.geometry.transmitters[0].position_m, dtype=states.dtype)
    east = states[..., motion.pos_idx[0]] - origin[0]
    north = states[..., motion.pos_idx[1]] - origin[1]
    dist = torch.hypot(east, north)
    speed = torch.linalg.vector_norm(states[..., list(motion.vel_idx)], dim=-1)
    az = torch.rad2deg(torch.atan2(east, north))
    # Compare the sector in a frame centred on its middle so that sectors across north work too.
    centre = 0.5 * (env.azimuth_deg[0] + env.azimuth_deg[1])
    half = 0.5 * (env.azimuth_deg[1] - env.azimuth_deg[0])
    off = torch.remainder(az - centre + 180.0, 360.0) - 180.0
    return {
        "range": ((dist < env.range_m[0]) | (dist > env.range_m[1])).any(-1),
        "speed": ((speed < env.speed_mps[0]) | (speed > env.speed_mps[1])).any(-1),
        "azimuth": (off.abs() > half).any(-1),
    }


def simulate_candidates(recipe: TrackRecipe, n: int, g: torch.Generator, motion, meas) -> TrackBatch:
    """Draw ``n`` tracks with no rejection."""
    mot = recipe.effective_motion()
    x0 = draw_initial_states(recipe, n, g)
    q = [mot.q_psd, mot.q_psd] + ([mot.q_psd_vertical] if recipe.dim == 3 else [])
    states = motion.sample(x0, mot.steps, mot.dt_s, q, generator=g)
    std = torch.stack([_uniform(iv, n, g) for iv in recipe.noise.intervals_si()], dim=-1)
    z = meas.sample(states, std, generator=g)
    return TrackBatch(states, z, std, envelope_violations(recipe, states, motion))


def _take(batch: TrackBatch, keep: torch.Tensor) -> TrackBatch:
    return TrackBatch(batch.states[keep], batch.measurements[keep], batch.noise_std[keep], {k: v[keep] for k, v in batch.violations.items()})


def _concat(parts: list[TrackBatch]) -> TrackBatch:
    return TrackBatch(
        torch.cat([p.states for p in parts]),
        torch.cat([p.measurements for p in parts]),
        torch.cat([p.noise_std for p in parts]),
        {k: torch.cat([p.violations[k] for p in parts]) for k in ENVELOPE_CRITERIA},
    )


def generate_tracks(recipe: TrackRecipe, n: int, g: torch.Generator) -> tuple[TrackBatch, DrawStats]:
    """Draw ``n`` accepted tracks of the recipe's variant, redrawing rejected candidates.

    Candidates are drawn in batches of at most ``n``; the sequence of draws depends only on the
    generator, so the same seed gives the same tracks. Raises :class:`ConfigError` when the
    acceptance rate is so low that ``max_draws_per_track * n`` candidates do not suffice.
    """
    motion, meas = build_models(recipe)
    stats, parts, have = DrawStats(), [], 0
    budget = recipe.envelope_variant.max_draws_per_track * n
    while have < n:
        if stats.drawn >= budget:
            rate = (stats.drawn - stats.rejected_envelope - stats.rejected_near_sensor) / max(stats.drawn, 1)
            raise ConfigError(
                f"only {rate:.2%} of drawn tracks are acceptable ({stats.drawn} drawn for {n}); "
                "the envelope cannot be met with these motion parameters"
            )
        cand = simulate_candidates(recipe, n - have, g, motion, meas)
        near = meas.near_sensor(cand.states, recipe.min_sensor_distance_m).any(-1)
        keep = ~near
        batch_stats = DrawStats(drawn=len(near), rejected_near_sensor=int(near.sum()))
        if recipe.variant == "envelope":
            out = cand.left_envelope & keep
            batch_stats.rejected_envelope = int(out.sum())
            for k, v in cand.violations.items():
                batch_stats.by_criterion[k] = int((v & keep).sum())
            keep &= ~cand.left_envelope
        stats.add(batch_stats)
        if bool(keep.any()):
            parts.append(_take(cand, keep))
            have += int(keep.sum())
    return _concat(parts), stats
