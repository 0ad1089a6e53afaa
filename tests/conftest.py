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


PRIOR_SD = (50.0, 3.0, 0.5)
"""Per-axis position (m), velocity (m/s) and acceleration (m/s^2) deviations of the test priors."""


def perturbed_prior(states0: torch.Tensor, seed: int = 0):
    """A Gaussian prior per track around the true first states ``(B, 6)`` (planar CA): the mean is
    the truth plus a draw of deviation :data:`PRIOR_SD`, the covariance that deviation squared."""
    from pmsr_nn.filters import Gaussian

    B = states0.shape[0]
    sd = torch.tensor(PRIOR_SD * 2, dtype=torch.float64)
    g = torch.Generator().manual_seed(seed)
    x0 = states0 + torch.randn(B, 6, generator=g, dtype=torch.float64) * sd
    return Gaussian(x0, torch.diag(sd**2).expand(B, 6, 6).clone())


@pytest.fixture
def captured(monkeypatch):
    """The figures the report functions make, laid out as they would be written and kept open
    (``save_figure`` of :mod:`pmsr_nn.harness.report.figures` and of the modules that import it)."""
    from pmsr_nn.harness.report import figures, track_figure, trajectory_figure

    figs = []

    def keep(fig, path, dpi=110, rect=None):
        figures.lay_out(fig, rect)
        fig.canvas.draw()
        figs.append(fig)
        return path

    for module in (figures, trajectory_figure, track_figure):
        monkeypatch.setattr(module, "save_figure", keep)
    yield figs
    for fig in figs:
        figures.pyplot().close(fig)
