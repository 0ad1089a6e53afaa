import os

import pytest
import torch

from pmsr_nn.simulation.recipe import TrackRecipe

# pmsr evaluate runs on every core by default; the suite already spreads over the cores (xdist), so
# each evaluate here stays in one process unless a test asks for workers
os.environ.setdefault("PMSR_WORKERS", "1")


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


def _blank_png() -> bytes:
    """A valid 1 x 1 PNG (what a figure not rendered in a test is written as)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", 1, 1, 8, 6, 0, 0, 0)  # 1 x 1, 8-bit RGBA
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\x00\x00\x00\x00\x00"))
            + chunk(b"IEND", b""))


@pytest.fixture(autouse=True)
def _figures_rendered_where_a_test_looks_at_them(request, monkeypatch):
    """Lay out and rasterise a figure (``Figure.savefig``) only in the tests marked ``figures``,
    which check what is drawn (``figure_check.assert_drawn_png``, the ``captured`` layouts); every
    other test still builds each figure, with all its artists, and gets a 1 x 1 PNG at its path.
    Rendering was about a third of the harness tests' time (``savefig`` with its constrained
    layout, about 0.7 s a figure). ``PMSR_TEST_RENDER_ALL=1`` renders everything."""
    if request.node.get_closest_marker("figures") is not None or os.environ.get("PMSR_TEST_RENDER_ALL") == "1":
        yield
        return
    from matplotlib.figure import Figure

    blank = _blank_png()

    def written_blank(self, fname, *args, **kwargs):
        if hasattr(fname, "write"):
            fname.write(blank)
        else:
            with open(fname, "wb") as f:
                f.write(blank)

    monkeypatch.setattr(Figure, "savefig", written_blank)
    yield
