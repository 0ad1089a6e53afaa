"""The CA track generator: initial states, envelope handling, noise, determinism."""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from pmsr_nn.errors import ConfigError
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.recipe import EnvelopeVariantSpec, TrackRecipe, load_recipe
from pmsr_nn.simulation.tracks import build_models, draw_initial_states, generate_tracks

ROOT = Path(__file__).resolve().parents[1]


def short(recipe: TrackRecipe, steps=200, **kw) -> TrackRecipe:
    return replace(recipe, window=min(recipe.window, steps), motion=replace(recipe.motion, steps=steps), **kw)


def test_recipe_file_equals_builtin_defaults():
    assert load_recipe(ROOT / "datasets" / "fitee2023_ca.yaml") == TrackRecipe()


def test_default_geometry_has_the_paper_baselines():
    _, meas = build_models(TrackRecipe())
    assert meas.geometry.baselines_m() == pytest.approx([7560.0, 8120.0, 8280.0])


def test_initial_states_follow_eqs_7_to_9():
    r = TrackRecipe(variant="literal")
    x0 = draw_initial_states(r, 20000, seeded_generator(0)).numpy()
    rng = np.hypot(x0[:, 0], x0[:, 3])
    bearing = np.degrees(np.arctan2(x0[:, 0], x0[:, 3]))
    speed, accel = np.hypot(x0[:, 1], x0[:, 4]), np.hypot(x0[:, 2], x0[:, 5])
    init = r.motion.initial
    for values, (lo, hi) in ((rng, init.range_m), (bearing, init.bearing_deg), (speed, init.speed_mps), (accel, init.accel_mps2)):
        assert values.min() >= lo - 1e-9 and values.max() <= hi + 1e-9
        # Uniform on [lo, hi]: the sample mean lies within 5 standard errors of the midpoint.
        assert abs(values.mean() - (lo + hi) / 2) < 5 * (hi - lo) / math.sqrt(12 * len(values))


def independent_envelope_check(recipe, states):
    """Table 1 recomputed with NumPy: (range, speed, azimuth) violations per track."""
    s = states.numpy()
    dist = np.hypot(s[..., 0], s[..., 3])
    speed = np.hypot(s[..., 1], s[..., 4])
    az = np.degrees(np.arctan2(s[..., 0], s[..., 3]))
    e = recipe.envelope
    return np.stack([
        ((dist < e.range_m[0]) | (dist > e.range_m[1])).any(-1),
        ((speed < e.speed_mps[0]) | (speed > e.speed_mps[1])).any(-1),
        ((az < e.azimuth_deg[0]) | (az > e.azimuth_deg[1])).any(-1),
    ], -1)


def test_envelope_variant_keeps_every_track_inside():
    r = short(TrackRecipe(), steps=1000)
    batch, stats = generate_tracks(r, 64, seeded_generator(1))
    assert batch.states.shape == (64, 1000, 6)
    assert not independent_envelope_check(r, batch.states).any()
    assert stats.rejected_envelope + (stats.initial_drawn - stats.initial_passed) > 0  # rejection did work
    assert 0 < stats.acceptance < 1


def test_literal_variant_reports_the_tracks_that_leave():
    r = short(TrackRecipe(variant="literal"), steps=1000)
    batch, stats = generate_tracks(r, 64, seeded_generator(2))
    flags = independent_envelope_check(r, batch.states)
    got = torch.stack([batch.violations[k] for k in ("range", "speed", "azimuth")], -1).numpy()
    np.testing.assert_array_equal(got, flags)
    assert flags.any(-1).mean() > 0.9  # the recipe as written leaves Table 1
    assert stats.rejected_envelope == 0


def test_measurements_are_h_of_truth_plus_per_track_noise():
    r = short(TrackRecipe(), steps=400)
    motion, meas = build_models(r)
    batch, _ = generate_tracks(r, 200, seeded_generator(3))
    lo_hi = r.noise.intervals_si()
    for c, (lo, hi) in enumerate(lo_hi):
        assert bool(((batch.noise_std[:, c] >= lo) & (batch.noise_std[:, c] <= hi)).all())
    err = meas.residual(batch.measurements, meas.h(batch.states))
    white = err / meas.std_vector(batch.noise_std)[:, None, :]
    n = white.shape[0] * white.shape[1]
    assert bool((white.mean((0, 1)).abs() < 5 / math.sqrt(n)).all())
    assert bool(((white.var((0, 1)) - 1).abs() < 5 * math.sqrt(2 / n)).all())


def test_tracks_near_a_sensor_are_redrawn():
    r = short(TrackRecipe(variant="literal", min_sensor_distance_m=3000.0), steps=50)
    batch, stats = generate_tracks(r, 40, seeded_generator(4))
    _, meas = build_models(r)
    assert stats.rejected_near_sensor > 0
    assert not bool(meas.near_sensor(batch.states, 3000.0).any())


def test_same_generator_same_tracks():
    r = short(TrackRecipe())
    a, _ = generate_tracks(r, 16, seeded_generator(5, 1))
    b, _ = generate_tracks(r, 16, seeded_generator(5, 1))
    c, _ = generate_tracks(r, 16, seeded_generator(5, 2))
    assert torch.equal(a.states, b.states) and torch.equal(a.measurements, b.measurements)
    assert not torch.equal(a.states, c.states)


def test_three_d_tracks_fly_level_at_their_altitude():
    r = short(TrackRecipe(dim=3, motion=replace(TrackRecipe().motion, initial=replace(TrackRecipe().motion.initial, altitude_m=(100.0, 300.0)))), steps=100)
    batch, _ = generate_tracks(r, 8, seeded_generator(6))
    z = batch.states[..., 6]
    assert batch.states.shape[-1] == 9 and batch.measurements.shape[-1] == 9
    assert bool(((z >= 100) & (z <= 300)).all()) and torch.equal(z, z[:, :1].expand_as(z))


def test_unreachable_envelope_is_a_clear_error():
    r = short(TrackRecipe(envelope_variant=EnvelopeVariantSpec(q_psd=4.0, accel_mps2=(4.0, 5.0), max_draws_per_track=3)), steps=1000)
    with pytest.raises(ConfigError, match="acceptable"):
        generate_tracks(r, 8, seeded_generator(7))


@pytest.mark.parametrize("spec,ok", [
    ({"position_m": (1.0, 2.0)}, True),
    ({"baseline_m": 10.0, "bearing_deg": 90.0}, True),
    ({"baseline_m": 10.0}, False),
    ({}, False),
    ({"position_m": (1.0, 2.0), "bearing_deg": 90.0}, False),
])
def test_receiver_spec_forms(spec, ok):
    from pmsr_nn.simulation.recipe import ReceiverSpec

    if ok:
        assert len(ReceiverSpec(**spec).resolve((0.0, 0.0))) == 2
    else:
        with pytest.raises(ConfigError):
            ReceiverSpec(**spec).resolve((0.0, 0.0))
