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
from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..motion import ConstantAcceleration
from .recipe import TrackRecipe

MEASUREMENT_COMPONENTS = ("range", "range_rate", "azimuth")
ENVELOPE_CRITERIA = ("range", "speed", "azimuth")
NOMINAL_GRID_STEPS = 10
"""Stride (in samples) of the noise-free pre-screen of the envelope variant."""


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


@dataclass
class DrawStats:
    """Candidate counts of the rejection stages (all zero rejections for the literal variant).

    ``initial_drawn`` initial states were drawn, of which ``initial_passed`` had a noise-free path
    inside the envelope (envelope variant only; surplus survivors are discarded unused);
    ``sampled`` noisy tracks were simulated, of which ``rejected_envelope`` left the envelope and
    ``rejected_near_sensor`` passed too close to a sensor.
    """

    initial_drawn: int = 0
    initial_passed: int = 0
    sampled: int = 0
    rejected_envelope: int = 0
    rejected_near_sensor: int = 0

    def add(self, other: "DrawStats") -> None:
        for k in vars(self):
            setattr(self, k, getattr(self, k) + getattr(other, k))

    @property
    def acceptance(self) -> float:
        """Fraction of drawn candidates that would be kept (product of the stage rates)."""
        kept = self.sampled - self.rejected_envelope - self.rejected_near_sensor
        return (self.initial_passed / max(self.initial_drawn, 1)) * (kept / max(self.sampled, 1))


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


def _concat(parts: list[TrackBatch]) -> TrackBatch:
    return TrackBatch(
        torch.cat([p.states for p in parts]),
        torch.cat([p.measurements for p in parts]),
        torch.cat([p.noise_std for p in parts]),
        {k: torch.cat([p.violations[k] for p in parts]) for k in ENVELOPE_CRITERIA},
    )


def _any(violations: dict[str, torch.Tensor]) -> torch.Tensor:
    return torch.stack(list(violations.values())).any(0)


def generate_tracks(recipe: TrackRecipe, n: int, g: torch.Generator) -> tuple[TrackBatch, DrawStats]:
    """Draw ``n`` accepted tracks of the recipe's variant, redrawing rejected candidates.

    For the envelope variant the rejection has two stages: initial states whose noise-free CA
    path leaves the envelope (checked every ``NOMINAL_GRID_STEPS`` samples) are redrawn before any
    noise is sampled (cheap), then noisy paths that leave at any sample are redrawn. The kept
    tracks are therefore distributed as Eqs. 7-9 with the envelope-variant values, conditioned on
    both paths staying inside.

    The sequence of draws depends only on the generator, so the same seed gives the same
    tracks. Raises :class:`ConfigError` once ``max_draws_per_track * n`` initial states have been
    drawn without filling the batch.
    """
    motion, meas = build_models(recipe)
    mot = recipe.effective_motion()
    q = [mot.q_psd, mot.q_psd] + ([mot.q_psd_vertical] if recipe.dim == 3 else [])
    envelope = recipe.variant == "envelope"
    stats, parts, have = DrawStats(), [], 0
    budget = recipe.envelope_variant.max_draws_per_track * n
    if envelope:
        times = torch.arange(0, mot.steps, NOMINAL_GRID_STEPS, dtype=torch.float64) * mot.dt_s
        grid_F = motion.F(times)  # (G, dim_x, dim_x)
    while have < n:
        need = n - have
        # Stage 1 (envelope variant): collect `need` initial states whose noise-free path
        # x(t) = F(t) x0 stays inside on the coarse grid. Drawing 4x at a time keeps the number
        # of small batches down; surplus candidates are discarded (and counted).
        x0_parts, got = [], 0
        while got < need:
            if stats.initial_drawn >= budget:
                raise ConfigError(
                    f"only {stats.acceptance:.2%} of drawn tracks are acceptable ({stats.initial_drawn} "
                    f"drawn for {n}); the envelope cannot be met with these motion parameters"
                )
            x0 = draw_initial_states(recipe, need if not envelope else 4 * need, g)
            stats.initial_drawn += len(x0)
            if envelope:
                nominal = torch.einsum("gij,bj->bgi", grid_F, x0)
                x0 = x0[~_any(envelope_violations(recipe, nominal, motion))]
            stats.initial_passed += len(x0)
            x0_parts.append(x0)
            got += len(x0)
        x0 = torch.cat(x0_parts)[:need]
        step = DrawStats(sampled=len(x0))
        states = motion.sample(x0, mot.steps, mot.dt_s, q, generator=g)
        viol = envelope_violations(recipe, states, motion)
        keep = ~_any(viol) if envelope else torch.ones(len(x0), dtype=torch.bool)
        step.rejected_envelope = int((~keep).sum())
        near = meas.near_sensor(states[keep], recipe.min_sensor_distance_m).any(-1)
        step.rejected_near_sensor = int(near.sum())
        keep[keep.clone()] = ~near
        if bool(keep.any()):
            states = states[keep] if not bool(keep.all()) else states
            std = torch.stack([_uniform(iv, len(states), g) for iv in recipe.noise.intervals_si()], dim=-1)
            z = meas.sample(states, std, generator=g)
            parts.append(TrackBatch(states, z, std, {k: v[keep] for k, v in viol.items()}))
            have += len(states)
        stats.add(step)
    if len(parts) == 1:
        return parts[0], stats
    return _concat(parts), stats
