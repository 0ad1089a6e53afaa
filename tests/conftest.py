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
