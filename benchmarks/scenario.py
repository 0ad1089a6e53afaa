"""The scenario the filter benchmarks share: CA 1T-3R recipe (envelope variant) tracks with a
noisy first fix (50 m, 3 m/s, 0.05 m/s^2) as the prior."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import torch

from pmsr_nn.filters import Gaussian
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.recipe import TrackRecipe
from pmsr_nn.simulation.tracks import build_models, generate_tracks


def ca_scenario(n_tracks: int, steps: int, device: str = "cpu") -> SimpleNamespace:
    """``motion, model, truth (B, K, 6), z (B, K, 9), R (B, 9, 9), prior, q`` on ``device``."""
    recipe = TrackRecipe()
    recipe = replace(recipe, window=steps, motion=replace(recipe.motion, steps=steps))
    motion, model = build_models(recipe)
    batch, _ = generate_tracks(recipe, n_tracks, seeded_generator(0))
    sd = torch.tensor([50.0, 3.0, 0.05] * 2, dtype=torch.float64)
    x0 = batch.states[:, 0] + torch.randn(n_tracks, 6, generator=seeded_generator(1), dtype=torch.float64) * sd
    prior = Gaussian(x0.to(device), torch.diag(sd**2).expand(n_tracks, 6, 6).contiguous().to(device))
    return SimpleNamespace(motion=motion, model=model, truth=batch.states.to(device), z=batch.measurements.to(device),
                           R=model.R(batch.noise_std).to(device), prior=prior, q=recipe.effective_motion().q_psd)


def first_block(path):
    """One run of a study (``path``, a scenario YAML): ``(scenario, setup, its first case, block 0's
    products)``, what the per-row benchmarks call each row on."""
    from pmsr_nn.harness.run.blocks import draw_block
    from pmsr_nn.harness.run.runner import prepare
    from pmsr_nn.harness.scenario.loading import load_any

    sc = load_any(path, mc_runs=1)
    setup = prepare(sc)
    return sc, setup, setup.cases[0], draw_block(setup, 0, 0)[1]
