"""A track-before-detect scene (satellites, one target, frames) and the ``rd_maps`` sensor product.

The scene is the seed's Section 4: a receiver at the origin, satellites moving on straight lines
over the ~40 s of the scene, one target flying a straight line at a known altitude, present over
frames ``appears_frame .. disappears_frame`` (1-based, inclusive, as the seed counts them).

The product (:class:`RangeDopplerMaps`) is made from the same :class:`~pmsr_nn.simulation.products.Truth`
as every other product, and lazily: ``frame(k)`` draws frame ``k``'s maps for every run of the
block from its own generator (``seed``, ``k``), so a method reads one frame at a time, the whole
block's maps are never held at once, and every method sees the same maps whatever order it asks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import torch

from ..config import require
from ..errors import ConfigError
from ..rng import seeded_generator
from ..simulation.products import DesignedTruth, ProductKind, SensorSetup, Truth, register_product
from .maps import MapGrid, MapSpec, Satellite, grid_covering, range_doppler, simulate_frame, transmitter_positions
from .multibernoulli import BirthBox


@dataclass(frozen=True)
class MapExtent:
    """A map's cells fixed by hand (the same for every transmitter): excess range ``range_m`` and
    Doppler ``doppler_hz``, each ``[lo, hi]``."""

    range_m: tuple[float, float]
    doppler_hz: tuple[float, float]

    def __post_init__(self) -> None:
        for name in ("range_m", "doppler_hz"):
            lo, hi = getattr(self, name)
            require(math.isfinite(lo) and math.isfinite(hi) and lo < hi, f"map_extent.{name} must be [lo, hi], lo < hi")


@dataclass(frozen=True)
class TBDScene:
    """Satellites, maps, SNRs (dB, one per satellite), frames and the target (planar CV at
    ``maps.altitude_m``: ``position_m`` / ``velocity_mps`` at ``appears_frame``)."""

    satellites: tuple[Satellite, ...]
    snr_db: tuple[float, ...]
    maps: MapSpec = MapSpec()
    birth_box: BirthBox = BirthBox()
    frames: int = 20
    frame_s: float = 2.0
    appears_frame: int = 5
    disappears_frame: int = 16
    position_m: tuple[float, float] = (140_000.0, 0.0)
    velocity_mps: tuple[float, float] = (-30.0, 100.0)
    map_extent: MapExtent | None = None

    def __post_init__(self) -> None:
        require(len(self.satellites) >= 1, "a scene needs at least one satellite")
        require(len(self.snr_db) == len(self.satellites),
                f"snr_db needs one value per satellite ({len(self.satellites)}), got {len(self.snr_db)}")
        require(all(math.isfinite(v) for v in self.snr_db), f"snr_db must be finite numbers, got {list(self.snr_db)}")
        require(2 <= self.frames <= 10_000 and self.frame_s > 0, "frames must be in [2, 10000] and frame_s positive")
        require(1 <= self.appears_frame <= self.disappears_frame <= self.frames,
                "need 1 <= appears_frame <= disappears_frame <= frames")
        require(all(math.isfinite(v) for v in (*self.position_m, *self.velocity_mps)),
                "the target's position_m and velocity_mps must be finite")

    @property
    def P(self) -> int:
        return len(self.satellites)

    def times(self) -> torch.Tensor:
        """Frame times ``(K,)`` (s; frame 1 at 0)."""
        return torch.arange(self.frames, dtype=torch.float64) * self.frame_s

    @cached_property
    def tx(self) -> torch.Tensor:
        """Satellite positions ``(K, P, 3)`` per frame."""
        return transmitter_positions(self.satellites, self.times())

    def truth(self) -> DesignedTruth:
        """The target's states ``(K, 1, 4)`` ``[x, vx, y, vy]`` (NaN while absent) and ``alive (K, 1)``."""
        k = torch.arange(self.frames, dtype=torch.float64) - (self.appears_frame - 1)
        x, y = self.position_m
        vx, vy = self.velocity_mps
        states = torch.stack([x + k * self.frame_s * vx, torch.full_like(k, vx), y + k * self.frame_s * vy,
                              torch.full_like(k, vy)], -1)
        frame = torch.arange(1, self.frames + 1)
        alive = (frame >= self.appears_frame) & (frame <= self.disappears_frame)
        states = torch.where(alive[:, None], states, torch.full_like(states, float("nan")))
        return DesignedTruth(states[:, None].contiguous(), alive[:, None])

    @cached_property
    def grid(self) -> MapGrid:
        """The maps' cells: ``map_extent`` if given (checked to hold the birth box and the target),
        else the smallest grid holding every state the birth box can reach (:func:`~.maps.grid_covering`)."""
        tx = self.tx
        lo, hi = self.birth_box.bounds()
        reach = grid_covering(lo, hi, tx, self.frame_s, self.maps)
        if self.map_extent is None:
            grid = reach
        else:
            e, s = self.map_extent, self.maps
            D = int(math.floor((e.doppler_hz[1] - e.doppler_hz[0]) / s.doppler_cell_hz)) + 1
            U = int(math.floor((e.range_m[1] - e.range_m[0]) / s.range_cell_m)) + 1
            grid = MapGrid(torch.full((self.P,), e.range_m[0], dtype=torch.float64),
                           torch.full((self.P,), e.doppler_hz[0], dtype=torch.float64), D, U,
                           s.range_cell_m, s.doppler_cell_hz)
            need_lo_r = reach.range0_m
            need_hi_r = reach.range0_m + (reach.U - 1) * reach.range_cell_m
            need_lo_f = reach.doppler0_hz
            need_hi_f = reach.doppler0_hz + (reach.D - 1) * reach.doppler_cell_hz
            for p, sat in enumerate(self.satellites):
                pad_r = (s.margin_cells + math.ceil(s.lobe_cells)) * s.range_cell_m
                pad_f = (s.margin_cells + 1) * s.doppler_cell_hz
                r_lo, r_hi = float(need_lo_r[p]) + pad_r, float(need_hi_r[p]) - pad_r
                f_lo, f_hi = float(need_lo_f[p]) + pad_f, float(need_hi_f[p]) - pad_f
                if r_lo < e.range_m[0] or r_hi > e.range_m[1] or f_lo < e.doppler_hz[0] or f_hi > e.doppler_hz[1]:
                    raise ConfigError(
                        f"the birth box is outside the map's coverage for {sat.name}: its states reach excess range "
                        f"{r_lo:.0f}..{r_hi:.0f} m and Doppler {f_lo:.1f}..{f_hi:.1f} Hz, the maps cover "
                        f"{e.range_m[0]:g}..{e.range_m[1]:g} m and {e.doppler_hz[0]:g}..{e.doppler_hz[1]:g} Hz")
        return grid

    def cells(self, x: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Fractional cells ``(d, u)`` float32 ``(..., P)`` of states ``x (..., 4)`` at frame ``k`` (0-based).

        Computed in float32 (the particles' bulk cost): the range formula has no cancellation, and
        its rounding (under 0.01 m of range, 1e-6 Hz) is far below a cell."""
        grid = self.grid
        rng, dop = range_doppler(x.to(torch.float32), self.tx[k].to(torch.float32), self.maps)
        return ((dop - grid.doppler0_hz.to(torch.float32)) / grid.doppler_cell_hz,
                (rng - grid.range0_m.to(torch.float32)) / grid.range_cell_m)


@dataclass
class RangeDopplerMaps:
    """The ``rd_maps`` product of a block: ``frame(k)`` gives maps ``(B, P, D, U)`` complex64 of
    frame ``k`` (0-based); ``truth_cells (B, K, P, 2)`` the target's fractional (Doppler, range)
    cells (NaN while absent), for the figures."""

    scene: TBDScene
    truth_x: torch.Tensor
    present: torch.Tensor
    seed: int

    @property
    def B(self) -> int:
        return self.truth_x.shape[0]

    def frame(self, k: int) -> torch.Tensor:
        sc = self.scene
        x = torch.nan_to_num(self.truth_x[:, k, 0])  # (B, 4); absent targets add nothing
        rng, dop = range_doppler(x, sc.tx[k], sc.maps)
        g = seeded_generator(self.seed, k)
        present = self.present[k].expand(self.B)
        return simulate_frame(rng, dop, present, torch.tensor(sc.snr_db, dtype=torch.float64), sc.grid, sc.maps, g)


def make_rd_maps(sensing: SensorSetup, truth: Truth, g: torch.Generator, g_prior: torch.Generator) -> RangeDopplerMaps:
    """The product from the truth: one 62-bit seed drawn from ``g`` names the block's maps."""
    seed = int(torch.randint(0, 2**62, (1,), generator=g))
    return RangeDopplerMaps(sensing.rd_maps, truth.x, truth.alive[:, 0], seed)


register_product(ProductKind("rd_maps", 3, make_rd_maps, lambda s: getattr(s, "rd_maps", None) is not None,
                             "per transmitter and frame: a range-Doppler map after coherent integration "
                             "(track-before-detect)"))
