"""Drone manoeuvres and heavy-tailed range errors in the track simulator (issue 17, item 3)."""

import hashlib
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from pmsr_nn.errors import ConfigError
from pmsr_nn.harness.scenario.case_spec import CaseSpec, SegmentSpec
from pmsr_nn.harness.scenario.trajectories import design_trajectory
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.flight import Schedule, integrate_manoeuvres
from pmsr_nn.simulation.recipe import (EnvelopeSpec, EnvelopeVariantSpec, ManoeuvreSpec, TrackRecipe, load_recipe,
                                       recipe_from_dict)
from pmsr_nn.simulation.tracks import build_models, generate_tracks, range_rows

ROOT = Path(__file__).resolve().parents[1]
DRONE = ROOT / "datasets" / "drone_manoeuvres.yaml"


with np.load(ROOT / "tests" / "data" / "draws_2ef52e8.npz") as _f:
    REFERENCE = dict(_f)
"""Draws computed at commit 2ef52e8, before manoeuvres and range outliers existed (every 25th
scan and the last of test_without_the_new_options_the_draws_are_those_of_before's tracks)."""
EPS = 2.2e-16  # float64 machine epsilon
SAME_NORMALS = torch.backends.cpu.get_cpu_capability() in ("AVX2", "AVX512")
"""Whether torch draws its float32 normals with its AVX2 kernel (any x86 CPU with AVX2 and FMA,
whatever its maker): those are the same bits everywhere (integer generator output through IEEE
operations). Its scalar kernel (a CPU without AVX2, or ``ATEN_CPU_CAPABILITY=default``) computes
log and cos otherwise: the same draws to a few float32 ulps (2e-6 measured on N(0, 1) draws)."""


def stream_position(g: torch.Generator) -> bytes:
    """The integer part of a CPU generator's state: mt19937's seed, position and 624 words
    (``get_state()``'s first 5016 bytes) and whether a double / float normal is cached (bytes
    5040, 5052). It moves only with the number and kind of draws, so it is the same on any CPU;
    the cached normals' values (computed by libm) are left out."""
    s = g.get_state().numpy().tobytes()
    assert len(s) == 5056, "torch's CPU generator state has another layout: see stream_position"
    return s[:5016] + s[5040:5044] + s[5052:5053]


def assert_as_recorded(got: np.ndarray, ref: np.ndarray, rounds: int, angles=None, what: str = "") -> None:
    """Element-wise ``|got - ref| <= tol * scale``, ``scale`` the largest ``|ref|`` of each component
    (last axis; the rounding of a sum is relative to its largest terms, not to a result near
    zero), angles compared modulo 2 pi (one near +-pi may wrap to the other side).

    ``tol = rounds * 4 * EPS * 10``: float64 rounding of ``rounds`` successive operations of up to
    4 terms each (first-order bound), times a safety factor of 10; plus 1e-5 where the float32
    normals may come from torch's scalar kernel (:data:`SAME_NORMALS`: a few float32 ulps of
    draws no larger than the component, 5e-7 of it measured). A changed draw moves the
    measurement or acceleration it enters by its deviation, 1e-3 of the component or more."""
    assert got.shape == ref.shape, what
    diff = got - ref
    if angles is not None:
        diff[..., angles] = np.remainder(diff[..., angles] + np.pi, 2 * np.pi) - np.pi
    scale = np.abs(ref).reshape(-1, ref.shape[-1]).max(0)
    tol = (rounds * 4 * EPS * 10 + (0.0 if SAME_NORMALS else 1e-5)) * scale
    bad = np.abs(diff) > tol
    worst = np.unravel_index(np.argmax(np.abs(diff) / np.maximum(tol, np.finfo(float).tiny)), diff.shape)
    assert not bad.any(), (f"{what}: {int(bad.sum())} of {bad.size} values differ from those of 2ef52e8 by more "
                           f"than the rounding; at {tuple(map(int, worst))}: {got[worst]!r} vs {ref[worst]!r}")


def with_steps(recipe: TrackRecipe, steps: int) -> TrackRecipe:
    return replace(recipe, window=min(recipe.window, steps), motion=replace(recipe.motion, steps=steps))


def open_sky(man: ManoeuvreSpec, steps: int = 1000, speed=(10.0, 20.0)) -> TrackRecipe:
    """Manoeuvres alone: no CA noise, no initial acceleration, an envelope nothing leaves (so no
    track is rejected and the kept tracks are distributed exactly as drawn)."""
    r = TrackRecipe(min_sensor_distance_m=0.0,
                    envelope=EnvelopeSpec(range_m=(0.0, 1e7), speed_mps=(0.0, 1e4), azimuth_deg=(-180.0, 180.0)),
                    envelope_variant=EnvelopeVariantSpec(q_psd=0.0, accel_mps2=(0.0, 0.0)))
    initial = replace(r.motion.initial, speed_mps=speed)
    return with_steps(replace(r, motion=replace(r.motion, manoeuvres=man, initial=initial)), steps)


def lateral_acceleration(states: torch.Tensor) -> torch.Tensor:
    """|v x a| / |v| per sample ``(B, K)`` of CA states (m/s^2)."""
    v, a = states[..., [1, 4]], states[..., [2, 5]]
    return (v[..., 0] * a[..., 1] - v[..., 1] * a[..., 0]).abs() / v.norm(dim=-1)


# -- defaults unchanged --------------------------------------------------------------------------

def test_without_the_new_options_the_draws_are_those_of_before():
    # generate_tracks(TrackRecipe() at 200 steps, 16 tracks, seeded_generator(5, 1)) against the
    # same call at commit 2ef52e8, before manoeuvres and range outliers existed. Exact: the
    # generator's integer state after the draws (sha256 of stream_position, first 16 hex digits,
    # computed at 2ef52e8), so one draw more, fewer or of another kind fails on any CPU.
    # To rounding: the arrays on every 25th scan and the last (REFERENCE); the states are CA
    # states propagated by cumulative sums over 200 scans, the measurements bistatic range,
    # range-rate and azimuth of them: rounds = 200 in assert_as_recorded (1.8e-12 of each
    # component; BLAS and vectorised maths of other CPUs moved them by 5e-16 of it).
    r = with_steps(TrackRecipe(), 200)
    g = seeded_generator(5, 1)
    batch, _ = generate_tracks(r, 16, g)
    assert hashlib.sha256(stream_position(g)).hexdigest()[:16] == "6efd781e98887f35"
    assert batch.states.shape == (16, 200, 6) and batch.measurements.shape == (16, 200, 9)
    scans = REFERENCE["tracks_scans"]
    assert scans.tolist() == [0, 25, 50, 75, 100, 125, 150, 175, 199]
    angles = build_models(r)[1].angle_mask.numpy()
    assert_as_recorded(batch.states.numpy()[:, scans], REFERENCE["tracks_states"], 200, what="states")
    assert_as_recorded(batch.measurements.numpy()[:, scans], REFERENCE["tracks_measurements"], 200, angles,
                       what="measurements")
    assert_as_recorded(batch.noise_std.numpy(), REFERENCE["tracks_noise_std"], 1, what="noise_std")
    # and the recipe's plain data (manifest, training-cache key) does not mention them
    d = TrackRecipe().to_dict()
    assert "manoeuvres" not in d["motion"] and "range_outlier_prob" not in d["noise"]
    assert load_recipe(ROOT / "datasets" / "fitee2023_ca.yaml").to_dict() == d


def test_drone_recipe_is_the_fitee_recipe_plus_manoeuvres_and_outliers():
    drone = load_recipe(DRONE)
    assert drone.motion.manoeuvres == ManoeuvreSpec()  # the file spells out the defaults
    assert (drone.noise.range_outlier_prob, drone.noise.range_outlier_scale) == (0.02, 10.0)
    base = replace(drone, name="fitee2023_ca", motion=replace(drone.motion, manoeuvres=None),
                   noise=replace(drone.noise, range_outlier_prob=0.0))
    assert base == TrackRecipe()
    assert recipe_from_dict(drone.to_dict()) == drone  # what a dataset manifest stores reads back


# -- manoeuvres ------------------------------------------------------------------------------------

def test_manoeuvring_tracks_are_reproducible_inside_the_envelope_and_kinematically_consistent():
    r = with_steps(load_recipe(DRONE), 400)
    a, stats = generate_tracks(r, 12, seeded_generator(7))
    b, _ = generate_tracks(r, 12, seeded_generator(7))
    c, _ = generate_tracks(r, 12, seeded_generator(8))
    assert torch.equal(a.states, b.states) and torch.equal(a.measurements, b.measurements)
    assert not torch.equal(a.states, c.states)
    assert a.states.shape == (12, 400, 6)
    s = a.states.numpy()
    e = r.envelope
    dist, speed = np.hypot(s[..., 0], s[..., 3]), np.hypot(s[..., 1], s[..., 4])
    az = np.degrees(np.arctan2(s[..., 0], s[..., 3]))
    assert dist.min() >= e.range_m[0] and dist.max() <= e.range_m[1] and speed.max() <= e.speed_mps[1]
    assert az.min() >= e.azimuth_deg[0] and az.max() <= e.azimuth_deg[1]
    assert 0 < stats.acceptance < 1
    # The state is a consistent CA state: the mean velocity over an interval is the trapezoid of
    # the sampled velocities up to dt^2/12 * max|jerk| (jerk of a ramped turn: a sqrt(1/ramp^2 +
    # omega^2), a <= 4 m/s^2, omega <= 20 deg/s) plus the integrator's heading lag a h / 2
    # (h = 0.05 s); the CA part (constant acceleration, jerk noise of 1e-7 m^2/s^5) adds < 0.01 m/s.
    man = r.motion.manoeuvres
    jerk = man.turn_accel_mps2[1] * math.hypot(1 / man.ramp_s, math.radians(man.max_turn_rate_deg_s))
    h = r.motion.dt_s / man.substeps
    tol = r.motion.dt_s**2 / 12 * jerk + man.turn_accel_mps2[1] * h / 2 + 0.01
    for p, v in ((0, 1), (3, 4)):
        mean_v = np.diff(s[..., p], axis=1) / r.motion.dt_s
        trapezoid = 0.5 * (s[:, 1:, v] + s[:, :-1, v])
        assert np.abs(mean_v - trapezoid).max() < tol


def _reference_turn_fraction(man: ManoeuvreSpec, steps: int, tracks: int, rng: np.random.Generator) -> np.ndarray:
    """Per-track fraction of the sample times 0..steps-1 at which the commanded lateral acceleration
    exceeds 1 m/s^2, for turns only (turn_probability 1, no cap active), from the description of the
    manoeuvres alone: quiet U(quiet_s), turn U(turn_s) at U(turn_accel_mps2), ramped in and out."""
    t = np.arange(steps, dtype=float)
    n_ep = int((steps - 1) / (man.quiet_s[0] + man.turn_s[0])) + 1
    quiet = rng.uniform(*man.quiet_s, (tracks, n_ep))
    dur = rng.uniform(*man.turn_s, (tracks, n_ep))
    acc = rng.uniform(*man.turn_accel_mps2, (tracks, n_ep))
    start = np.cumsum(quiet, 1) + np.concatenate([np.zeros((tracks, 1)), np.cumsum(dur, 1)[:, :-1]], 1)
    end = start + dur
    r = man.ramp_s
    lateral = np.zeros((tracks, steps))
    for e in range(n_ep):  # episodes never overlap (quiet >= ramp): their ramped profiles add
        w = np.clip((t - start[:, e:e + 1]) / r, 0, 1) - np.clip((t - end[:, e:e + 1]) / r, 0, 1)
        lateral += acc[:, e:e + 1] * w
    return (lateral > 1.0).mean(1)


@pytest.mark.integration
def test_turns_take_the_share_of_time_their_description_implies():
    man = ManoeuvreSpec(quiet_s=(30.0, 60.0), turn_probability=1.0, turn_accel_mps2=(2.0, 3.0), turn_s=(20.0, 40.0),
                        max_turn_rate_deg_s=90.0, ramp_s=1.0)  # cap 1.57 rad/s x >= 10 m/s: never active
    r = open_sky(man)
    batch, stats = generate_tracks(r, 64, seeded_generator(11))
    assert stats.rejected_envelope == 0 and stats.initial_passed == stats.initial_drawn
    speed = batch.states[..., [1, 4]].norm(dim=-1)
    assert float((speed - speed[:, :1]).abs().max()) < 1e-6  # turns only: speed kept (to rounding)
    got = (lateral_acceleration(batch.states) > 1.0).double().mean(1).numpy()
    ref = _reference_turn_fraction(man, r.motion.steps, 4000, np.random.default_rng(0))
    # ~ 30 s of turn per 75 s cycle: 0.4 of the time, less the ramp tails below 1 m/s^2
    assert 0.3 < ref.mean() < 0.45
    se = math.sqrt(got.var(ddof=1) / len(got) + ref.var(ddof=1) / len(ref))
    assert abs(got.mean() - ref.mean()) < 4 * se


def test_speed_changes_stay_in_their_band_and_reach_it():
    man = ManoeuvreSpec(quiet_s=(10.0, 20.0), turn_probability=0.0, speed_mps=(8.0, 16.0), ramp_s=2.0)
    r = open_sky(man, steps=600, speed=(10.0, 14.0))
    batch, _ = generate_tracks(r, 32, seeded_generator(12))
    speed = batch.states[..., [1, 4]].norm(dim=-1)
    # speed integrated by sub-steps of h: a ramp's left sum is off by at most a h / 2 each way
    tol = man.speed_change_mps2[1] * r.motion.dt_s / man.substeps
    assert float(speed.min()) > 8.0 - tol and float(speed.max()) < 16.0 + tol
    assert float(speed.min()) < 8.5 and float(speed.max()) > 15.5  # shortened changes end at the edges
    heading = torch.atan2(batch.states[..., 1], batch.states[..., 4])
    assert float((heading - heading[:, :1]).abs().max()) < 1e-9  # no turns: a straight line


def test_the_simulator_flies_what_the_designed_trajectories_fly():
    r = TrackRecipe()
    case = CaseSpec("c", 5000.0, 90.0, 12.0, 30.0, (SegmentSpec(50.0), SegmentSpec(30.0, across_mps2=2.0),
                                                    SegmentSpec(60.0), SegmentSpec(10.0, along_mps2=-1.0),
                                                    SegmentSpec(50.0)))
    truth = design_trajectory(case, r, 2.0)
    schedule = Schedule(*(torch.tensor([v], dtype=torch.float64) for v in ([50.0, 140.0], [80.0, 150.0],
                                                                            [0.0, -1.0], [2.0, 0.0])))
    flown = integrate_manoeuvres(truth[:1], schedule, len(truth), r.motion.dt_s, 2.0, 100)[0]
    # same kinematics and sub-step: only rounding differs (sin/cos of float vs tensor, the clock)
    assert float((flown - truth).abs().max()) < 1e-8
    assert float(lateral_acceleration(truth[None]).max()) == pytest.approx(2.0, abs=1e-9)


# -- heavy-tailed range errors ---------------------------------------------------------------------

def test_range_outliers_come_at_their_rate_and_only_on_ranges():
    p, scale = 0.05, 10.0
    r = with_steps(replace(TrackRecipe(), noise=replace(TrackRecipe().noise, range_outlier_prob=p,
                                                        range_outlier_scale=scale)), 300)
    batch, _ = generate_tracks(r, 40, seeded_generator(13))
    _, meas = build_models(r)
    white = meas.residual(batch.measurements, meas.h(batch.states)) / meas.std_vector(batch.noise_std)[:, None, :]
    rows = range_rows(meas)
    ranges = white[..., rows]
    n = ranges.numel()
    # |error| > 6 deviations: an outlier with |N| > 0.6; never a nominal error (float32 normals stop at ~5.8)
    expected = p * math.erfc(0.6 / math.sqrt(2))
    count = int((ranges.abs() > 6).sum())
    assert abs(count - n * expected) < 4 * math.sqrt(n * expected * (1 - expected))
    others = torch.ones(white.shape[-1], dtype=torch.bool)
    others[rows] = False
    assert float(white[..., others].abs().max()) < 6  # range-rate and azimuth untouched


@pytest.mark.parametrize("patch, message", [
    ({"noise": {"range_outlier_prob": 1.5}}, "noise.range_outlier_prob must be in"),
    ({"noise": {"range_outlier_scale": 0.5}}, "noise.range_outlier_scale must be at least 1"),
    ({"motion": {"manoeuvres": {"quiet_s": [1.0, 5.0]}}}, "quiet_s must be at least ramp_s"),
    ({"motion": {"manoeuvres": {"turn_probability": 2}}}, "turn_probability must be in"),
    ({"motion": {"manoeuvres": {"speed_change_mps2": [0.0, 1.0]}}}, "speed_change_mps2: must be positive"),
    ({"motion": {"manoeuvres": {"turn_s": [20.0, 10.0]}}}, "turn_s: lower end"),
    ({"motion": {"manoeuvres": {"ramp_s": 0}}}, "ramp_s must be positive"),
    ({"motion": {"manoeuvres": {"quiet_s": [0.01, 0.02], "ramp_s": 0.01, "turn_s": [0.0, 1.0]}}}, "episodes per track"),
    ({"motion": {"manoeuvres": {"turn_rate": 3}}}, "unknown key 'turn_rate'"),
    ({"dim": 3, "motion": {"manoeuvres": {}}}, "manoeuvring tracks are planar"),
])
def test_bad_manoeuvre_and_outlier_settings_are_one_line_errors(patch, message):
    d = TrackRecipe().to_dict()
    for key, value in patch.items():
        if isinstance(value, dict):
            for k, v in value.items():
                d[key][k] = v
        else:
            d[key] = value
    with pytest.raises(ConfigError, match=message) as exc:
        recipe_from_dict(d)
    assert "\n" not in str(exc.value)
