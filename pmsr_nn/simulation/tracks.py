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

With ``motion.manoeuvres`` (planar recipes) a track is the CA track above plus drone manoeuvres:
the flight of :mod:`.flight` (quiet stretches, coordinated turns, speed changes) from the drawn
position and velocity, plus the CA process started at zero position and velocity with the drawn
acceleration and the recipe's jerk PSD (linear, so it adds). The envelope variant's noise-free
pre-screen then uses the flight plus the drawn acceleration's drift. With
``noise.range_outlier_prob > 0`` some range errors are scaled up (:func:`apply_range_outliers`).
Both off, the draws are exactly those of a recipe without the options.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..motion import ConstantAcceleration
from .flight import draw_schedule, integrate_manoeuvres
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


def range_rows(model: MeasurementModel) -> torch.Tensor:
    """Indices of the bistatic-range rows of ``model``'s measurement vector."""
    return torch.tensor([i for i, label in enumerate(model.labels) if label.rsplit("_", 1)[0] == "range"],
                        dtype=torch.long)


def apply_range_outliers(z: torch.Tensor, clean: torch.Tensor, rows: torch.Tensor, prob: float, scale: float,
                         g: torch.Generator) -> torch.Tensor:
    """Heavy-tailed range errors: each range measurement of ``z (..., K, m)`` (rows ``rows``) is,
    with probability ``prob`` and independently, moved to ``clean + scale * (z - clean)`` (its
    error's deviation times ``scale``); ``clean`` broadcasts against ``z``. Draws one uniform per
    range measurement from ``g``, and nothing at all when ``prob`` is 0 (``z`` returned as is)."""
    if prob <= 0.0:
        return z
    zr = z[..., rows]
    cr = clean[..., rows].expand_as(zr)
    hit = torch.rand(zr.shape, generator=g, dtype=torch.float64) < prob
    z = z.clone()
    z[..., rows] = torch.where(hit, cr + scale * (zr - cr), zr)
    return z


def _manoeuvring(recipe: TrackRecipe, x0: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    """Noise-free manoeuvring flights ``(B, K, 6)`` from initial states ``x0 (B, 6)`` (position and
    velocity; the drawn acceleration is added by the caller's CA part)."""
    mot, man = recipe.motion, recipe.motion.manoeuvres
    schedule = draw_schedule(man, torch.hypot(x0[:, 1], x0[:, 4]), (mot.steps - 1) * mot.dt_s, g)
    return integrate_manoeuvres(x0, schedule, mot.steps, mot.dt_s, man.ramp_s, man.substeps)


def _acceleration_only(x0: torch.Tensor, motion: ConstantAcceleration) -> torch.Tensor:
    """``x0`` with position and velocity zeroed (the CA part added to a manoeuvring flight)."""
    a0 = torch.zeros_like(x0)
    a0[:, list(motion.acc_idx)] = x0[:, list(motion.acc_idx)]
    return a0


MAX_FLIGHTS_PER_ROUND = 2048
"""Most manoeuvring flights integrated at once (about 100 kB each for 1000 samples)."""

MIN_FLIGHTS_PER_ROUND = 256
"""Fewest: a round's cost is nearly that of its time loop whatever the batch, so rounds are big."""


def _manoeuvre_round(need: int, missing: int, stats: DrawStats, envelope: bool) -> tuple[int, int]:
    """Manoeuvring tracks: how many stage-1 survivors to collect (``want``: enough for ``need``
    kept tracks at the stage-2 rate seen so far) and how many initial states to draw for
    ``missing`` more survivors (``batch``, at the stage-1 rate seen so far). The kept tracks (the
    first accepted in draw order) are distributed alike whatever the sizes, but which draws they
    come from depends on them: changing this rule changes the tracks a seed gives."""
    if not envelope:
        return min(need, MAX_FLIGHTS_PER_ROUND), min(missing, MAX_FLIGHTS_PER_ROUND)
    pass1 = stats.initial_passed / stats.initial_drawn if stats.initial_drawn else 0.25
    kept = stats.sampled - stats.rejected_envelope - stats.rejected_near_sensor
    pass2 = kept / stats.sampled if stats.sampled else 0.75
    want = min(max(need, math.ceil(1.2 * need / max(pass2, 0.05))), MAX_FLIGHTS_PER_ROUND)
    batch = min(max(MIN_FLIGHTS_PER_ROUND, math.ceil(1.2 * missing / max(pass1, 0.01))), MAX_FLIGHTS_PER_ROUND)
    return want, batch


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
    manoeuvres = mot.manoeuvres is not None
    if manoeuvres:
        all_F = motion.F(torch.arange(mot.steps, dtype=torch.float64) * mot.dt_s)  # (K, dim_x, dim_x)
    while have < n:
        need = n - have
        # Stage 1 (envelope variant): collect `need` initial states whose noise-free path
        # x(t) = F(t) x0 stays inside on the coarse grid (with manoeuvres: the flight plus the
        # drift of the drawn acceleration, at every sample). Drawing 4x at a time keeps the number
        # of small batches down; surplus candidates are discarded (and counted).
        want, batch = need, need if not envelope else 4 * need
        if manoeuvres:  # a round of flights costs ~1 s whatever its size: size rounds from the rates seen so far
            want, batch = _manoeuvre_round(need, need, stats, envelope)
        x0_parts, flight_parts, got = [], [], 0
        while got < want:
            if stats.initial_drawn >= budget:
                raise ConfigError(
                    f"only {stats.acceptance:.2%} of drawn tracks are acceptable ({stats.initial_drawn} "
                    f"drawn for {n}); the envelope cannot be met with these motion parameters"
                )
            if manoeuvres and got:
                batch = _manoeuvre_round(need, want - got, stats, envelope)[1]
            x0 = draw_initial_states(recipe, batch, g)
            stats.initial_drawn += len(x0)
            flight = _manoeuvring(recipe, x0, g) if manoeuvres else None
            if envelope:
                if manoeuvres:
                    nominal = flight + torch.einsum("gij,bj->bgi", all_F, _acceleration_only(x0, motion))
                else:
                    nominal = torch.einsum("gij,bj->bgi", grid_F, x0)
                inside = ~_any(envelope_violations(recipe, nominal, motion))
                x0 = x0[inside]
                flight = flight[inside] if manoeuvres else None
            stats.initial_passed += len(x0)
            x0_parts.append(x0)
            flight_parts.append(flight)
            got += len(x0)
        # every survivor of a manoeuvring round goes on (their flights are paid for), else `need`
        take = min(got, MAX_FLIGHTS_PER_ROUND) if manoeuvres else need
        x0 = torch.cat(x0_parts)[:take]
        step = DrawStats(sampled=len(x0))
        if manoeuvres:
            states = torch.cat(flight_parts)[:take] + motion.sample(_acceleration_only(x0, motion), mot.steps,
                                                                    mot.dt_s, q, generator=g)
        else:
            states = motion.sample(x0, mot.steps, mot.dt_s, q, generator=g)
        viol = envelope_violations(recipe, states, motion)
        keep = ~_any(viol) if envelope else torch.ones(len(x0), dtype=torch.bool)
        step.rejected_envelope = int((~keep).sum())
        near = meas.near_sensor(states[keep], recipe.min_sensor_distance_m).any(-1)
        step.rejected_near_sensor = int(near.sum())
        keep[keep.clone()] = ~near
        if take > need:  # surplus accepted candidates (manoeuvres) are discarded unused
            keep &= keep.cumsum(0) <= need
        if bool(keep.any()):
            states = states[keep] if not bool(keep.all()) else states
            std = torch.stack([_uniform(iv, len(states), g) for iv in recipe.noise.intervals_si()], dim=-1)
            z = meas.sample(states, std, generator=g)
            if recipe.noise.range_outlier_prob > 0:
                z = apply_range_outliers(z, meas.h(states), range_rows(meas), recipe.noise.range_outlier_prob,
                                         recipe.noise.range_outlier_scale, g)
            parts.append(TrackBatch(states, z, std, {k: v[keep] for k, v in viol.items()}))
            have += len(states)
        stats.add(step)
    if len(parts) == 1:
        return parts[0], stats
    return _concat(parts), stats
