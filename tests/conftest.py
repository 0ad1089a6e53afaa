import pytest
import torch

from pmsr_nn.simulation.recipe import TrackRecipe


@pytest.fixture(autouse=True)
def _float64_and_threads():
    torch.set_default_dtype(torch.float64)
    yield
    torch.set_default_dtype(torch.float32)


@pytest.fixture
def small_recipe() -> TrackRecipe:
    """The default recipe, shortened so a dataset takes milliseconds."""
    from dataclasses import replace

    r = TrackRecipe()
    return replace(r, tracks=24, window=20, motion=replace(r.motion, steps=120), storage=replace(r.storage, chunk_tracks=10))


@pytest.fixture(scope="session")
def make_tracks():
    """``make_tracks(steps, n, seed) -> (motion, model, batch)``: ``n`` tracks of the default
    recipe shortened to ``steps`` samples (window = steps), drawn with ``seeded_generator(seed)``."""
    from dataclasses import replace

    from pmsr_nn.rng import seeded_generator
    from pmsr_nn.simulation.tracks import build_models, generate_tracks

    def make(steps: int, n: int, seed: int):
        r = TrackRecipe()
        recipe = replace(r, window=steps, motion=replace(r.motion, steps=steps))
        motion, model = build_models(recipe)
        batch, _ = generate_tracks(recipe, n, seeded_generator(seed))
        return motion, model, batch

    return make
