"""What forms a case's range-Doppler maps, and the ``rd_maps`` sensor product (its maker
:func:`make_rd_maps`, listed in :mod:`pmsr_nn.product_kinds`).

* :class:`MapScene`: ``P`` maps, one per transmitter-receiver pair (a transmitter moving on a
  straight line, a satellite, or fixed, an FM mast; a receiver anywhere on or above the ground),
  the map formation (:class:`~.maps.MapSpec`), the SNR of each map, the birth box of the filters,
  the frames (a case's scans) and which columns of the truth's state are the planar CV state
  ``[x, vx, y, vy]`` the maps and the filters use.
* :class:`RDMapsSpec`: a designed scenario's ``rd_maps:`` section (YAML), made into a
  :class:`MapScene` per case by :func:`build_scene` (the transmitters it lists, seen by one
  receiver, or every transmitter-receiver pair of the scenario's recipe).
* :class:`TBDScene`: a stand-alone scene of satellites and one straight-flying target (the
  seed's Section 4) with its own truth, for the unit tests and :mod:`.run`.

The product (:class:`RangeDopplerMaps`) is made from the same :class:`~pmsr_nn.simulation.products.Truth`
as every other product, and lazily: ``frame(k)`` draws frame ``k``'s maps for every run of the
block from its own generator (``seed``, ``k``), so a method reads one frame at a time, the whole
block's maps are never held at once, and every method sees the same maps whatever order it asks.
Every living target of the truth adds its response (its own random phase per frame and map).
"""

from __future__ import annotations

import math
import dataclasses
from dataclasses import dataclass
from functools import cached_property

import torch

from ..config import require
from ..errors import ConfigError
from ..rng import seeded_generator
from ..simulation.products import DesignedTruth, SensorSetup, Truth
from .maps import MapGrid, MapSpec, Satellite, grid_covering, range_doppler, simulate_frame
from .multibernoulli import BirthBox

GNSS_WAVELENGTH_M = 0.19
"""The seed's wavelength (GPS L1), what a :class:`TBDScene` of satellites uses when its maps give none."""

MIN_REACH_CELLS = 4
"""Fewest range cells (per map) the surveillance area may span: below, the maps say where a target
is no better than whether one is. Doppler is not held to it: its span is the birth box's velocity
spread, which a study may narrow to a known target's speed."""

MAX_MAP_CELLS = 20_000_000
"""Most cells a map may have (Doppler rows x range columns): a block's frame holds runs x maps of them."""


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


def _triples(values, what: str) -> tuple[tuple[float, float, float], ...]:
    out = tuple(tuple(float(v) for v in p) for p in values)
    require(all(len(p) == 3 and all(math.isfinite(v) for v in p) for p in out), f"{what} must be [x, y, z] each")
    return out


@dataclass(frozen=True)
class MapScene:
    """The maps of one case (module docstring): per map ``names``, the transmitter's position at
    time 0 and velocity (``tx_position_m``, ``tx_velocity_mps``), the receiver's position
    ``rx_position_m``, the carrier wavelength and the SNR (dB); the formation ``maps``, the
    filters' ``birth_box``, ``frames`` of ``frame_s`` s (frame ``k`` at ``k frame_s``), optional
    ``map_extent`` and ``state_index``: the truth's columns of ``[x, vx, y, vy]``."""

    names: tuple[str, ...]
    tx_position_m: tuple[tuple[float, float, float], ...]
    tx_velocity_mps: tuple[tuple[float, float, float], ...]
    rx_position_m: tuple[tuple[float, float, float], ...]
    wavelength_m: tuple[float, ...]
    snr_db: tuple[float, ...]
    maps: MapSpec
    birth_box: BirthBox
    frames: int
    frame_s: float
    map_extent: MapExtent | None = None
    state_index: tuple[int, int, int, int] = (0, 1, 2, 3)

    def __post_init__(self) -> None:
        P = len(self.names)
        require(P >= 1, "a scene needs at least one map")
        for what in ("tx_position_m", "tx_velocity_mps", "rx_position_m", "wavelength_m", "snr_db"):
            require(len(getattr(self, what)) == P, f"{what} needs one entry per map ({P}), got {len(getattr(self, what))}")
        require(all(math.isfinite(v) for v in self.snr_db), f"snr_db must be finite numbers, got {list(self.snr_db)}")
        require(all(math.isfinite(v) and v > 0 for v in self.wavelength_m), "wavelengths must be positive")
        require(1 <= self.frames <= 10_000 and self.frame_s > 0, "frames must be in [1, 10000] and frame_s positive")

    @property
    def P(self) -> int:
        return len(self.names)

    def times(self) -> torch.Tensor:
        """Frame times ``(K,)`` (s; frame 1 at 0)."""
        return torch.arange(self.frames, dtype=torch.float64) * self.frame_s

    @cached_property
    def tx(self) -> torch.Tensor:
        """Transmitter positions ``(K, P, 3)`` per frame (straight lines over the short scene)."""
        p0 = torch.tensor(self.tx_position_m, dtype=torch.float64)
        v = torch.tensor(self.tx_velocity_mps, dtype=torch.float64)
        return p0 + self.times()[:, None, None] * v

    @cached_property
    def rx(self) -> torch.Tensor:
        """Receiver positions ``(P, 3)``."""
        return torch.tensor(self.rx_position_m, dtype=torch.float64)

    @cached_property
    def wavelength(self) -> torch.Tensor:
        """Carrier wavelengths ``(P,)`` (m)."""
        return torch.tensor(self.wavelength_m, dtype=torch.float64)

    def range_doppler(self, x: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Excess range (m) and Doppler (Hz) ``(..., P)`` of CV states ``x (..., 4)`` at frame ``k``,
        on ``x``'s device."""
        return range_doppler(x, self.tx[k].to(x.device, x.dtype), self.maps, self.rx.to(x.device, x.dtype),
                             self.wavelength)

    @cached_property
    def grid(self) -> MapGrid:
        """The maps' cells: ``map_extent`` if given (checked to hold what the birth box can
        reach), else the smallest grid holding every state the birth box can reach
        (:func:`~.maps.grid_covering`); a one-line :class:`ConfigError` otherwise."""
        lo, hi = self.birth_box.bounds()
        reach = grid_covering(lo, hi, self.tx, self.frame_s, self.maps, rx=self.rx, wavelength=self.wavelength)
        span = reach.reach_cells[1]
        if bool((span < MIN_REACH_CELLS).any()):
            p = int(span.argmin())
            raise ConfigError(f"map {self.names[p]}: its range cells of {self.maps.range_cell_m:.0f} m give "
                              f"{float(span[p]):.1f} cells over the surveillance area (the excess ranges the birth "
                              f"box reaches), fewer than {MIN_REACH_CELLS}: the maps can not localise a target there; "
                              "use finer cells (a wider maps.bandwidth_hz or a higher sample_rate_hz)")
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
            for p, name in enumerate(self.names):
                pad_r = (s.margin_cells + math.ceil(s.lobe_cells)) * s.range_cell_m
                pad_f = (s.margin_cells + 1) * s.doppler_cell_hz
                r_lo, r_hi = float(need_lo_r[p]) + pad_r, float(need_hi_r[p]) - pad_r
                f_lo, f_hi = float(need_lo_f[p]) + pad_f, float(need_hi_f[p]) - pad_f
                if r_lo < e.range_m[0] or r_hi > e.range_m[1] or f_lo < e.doppler_hz[0] or f_hi > e.doppler_hz[1]:
                    raise ConfigError(
                        f"the birth box is outside the map's coverage for {name}: its states reach excess range "
                        f"{r_lo:.0f}..{r_hi:.0f} m and Doppler {f_lo:.1f}..{f_hi:.1f} Hz, the maps cover "
                        f"{e.range_m[0]:g}..{e.range_m[1]:g} m and {e.doppler_hz[0]:g}..{e.doppler_hz[1]:g} Hz; "
                        "widen rd_maps.map_extent or shrink the birth box")
        if grid.D * grid.U > MAX_MAP_CELLS:
            raise ConfigError(f"the maps would have {grid.D} Doppler x {grid.U} range cells, more than "
                              f"{MAX_MAP_CELLS:,}: shrink the birth box, coarsen the cells or give rd_maps.map_extent")
        return grid

    def cells(self, x: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Fractional cells ``(d, u)`` float32 ``(..., P)`` of states ``x (..., 4)`` at frame ``k`` (0-based).

        Computed in float32 (the particles' bulk cost): the range formula has no cancellation, each
        transmitter's offset from its receiver is formed in float64 first, and the rounding (under
        0.01 m of range, 1e-6 Hz) is far below a cell. On ``x``'s device (the scene's own tensors,
        made once on the CPU, are moved there)."""
        grid = self.grid
        f32 = lambda t: t.to(x.device, torch.float32)
        rng, dop = range_doppler(f32(x), f32(self.tx[k]), self.maps, f32(self.rx), self.wavelength)
        return (dop - f32(grid.doppler0_hz)) / grid.doppler_cell_hz, (rng - f32(grid.range0_m)) / grid.range_cell_m

    def cv_states(self, x: torch.Tensor) -> torch.Tensor:
        """The planar CV states ``(..., 4)`` ``[x, vx, y, vy]`` of truth states ``x (..., n)``."""
        return x[..., list(self.state_index)]

    def from_cv(self, x: torch.Tensor, n: int) -> torch.Tensor:
        """States ``(..., n)`` of the truth's space from CV states ``(..., 4)`` (other columns 0)."""
        out = x.new_zeros(*x.shape[:-1], n)
        out[..., list(self.state_index)] = x
        return out

    def check(self, x: torch.Tensor, alive: torch.Tensor, case: str, targets: list[str]) -> list[str]:
        """Refusals (one line each) of a case whose truth ``x (K, N, n)``, ``alive (K, N)`` the maps
        can not hold: the birth box outside a given extent, maps too large, a living target outside
        the maps' cells (at the first frame it leaves)."""
        try:
            grid = self.grid
        except ConfigError as exc:
            return [f"case {case!r}: {exc}"]
        out = []
        for n, name in enumerate(targets):
            for k in torch.nonzero(alive[:, n])[:, 0].tolist():
                d, u = self.cells(self.cv_states(x[k, n]), k)
                bad = (d < 0) | (d > grid.D - 1) | (u < 0) | (u > grid.U - 1)
                if bool(bad.any()):
                    p = int(bad.to(torch.int64).argmax())
                    out.append(f"case {case!r}: target {name!r} leaves the maps at frame {k + 1} (map {self.names[p]}: "
                               f"Doppler cell {float(d[p]):.1f} of 0..{grid.D - 1}, range cell {float(u[p]):.1f} of "
                               f"0..{grid.U - 1}); the maps cover what the birth box can reach: widen rd_maps.birth_box "
                               "(or rd_maps.map_extent) to hold the target's track")
                    break
        return out


@dataclass(frozen=True)
class RDMapsSpec:
    """A scenario's ``rd_maps:`` section: range-Doppler maps for track-before-detect methods.

    ``snr_db``: one value for every map or one per map; ``birth_box``: where the filters' births
    are drawn from (planar CV, the maps cover what it can reach unless ``map_extent`` fixes their
    cells); ``maps``: the map formation; ``transmitters``: moving transmitters (satellites:
    ``position_m`` and ``velocity_mps`` at time 0, ``[x, y, z]``) seen by one receiver at
    ``receiver_m``; without them, every transmitter-receiver pair of the scenario's recipe makes a
    map (fixed transmitters on the ground, each map on its transmitter's carrier unless ``maps``
    gives one); ``table_frame``: the frame (1-based) of the report's detected-rate table (null:
    the last frame a target lives)."""

    snr_db: tuple[float, ...]
    birth_box: BirthBox
    maps: MapSpec = MapSpec()
    transmitters: tuple[Satellite, ...] = ()
    receiver_m: tuple[float, float, float] | None = None
    map_extent: MapExtent | None = None
    table_frame: int | None = None

    def __post_init__(self) -> None:
        require(len(self.snr_db) >= 1, "rd_maps.snr_db needs one value, or one per map")
        require(all(math.isfinite(v) for v in self.snr_db), f"rd_maps.snr_db must be finite numbers, got {list(self.snr_db)}")
        require(self.table_frame is None or self.table_frame >= 1, "rd_maps.table_frame must be a frame (1-based) or null")
        if self.transmitters:
            P = len(self.transmitters)
            require(self.receiver_m is not None, "rd_maps.transmitters are seen by one receiver: give rd_maps.receiver_m "
                                                 "([x, y, z], m)")
            require(all(math.isfinite(v) for v in self.receiver_m), "rd_maps.receiver_m must be 3 finite values")
            require(len(self.snr_db) in (1, P), f"rd_maps.snr_db needs one value or one per map ({P} transmitters), "
                                                f"got {len(self.snr_db)}")
            require(self.maps.wavelength is not None, "rd_maps.maps needs wavelength_m or carrier_hz: the listed "
                                                      "transmitters carry none")
            names = [t.name for t in self.transmitters]
            dup = sorted({n for n in names if names.count(n) > 1})
            require(not dup, f"rd_maps.transmitters: duplicate name(s) {dup}")
        else:
            require(self.receiver_m is None, "rd_maps.receiver_m goes with rd_maps.transmitters (without them every "
                                             "pair of the recipe makes a map, each with its own receiver)")

    def snr_per_map(self, P: int, what: str) -> tuple[float, ...]:
        """One SNR per map (a single value repeated), or a one-line error naming ``what`` the maps are."""
        if len(self.snr_db) not in (1, P):
            raise ConfigError(f"rd_maps.snr_db needs one value or one per map ({P} maps: {what}), got {len(self.snr_db)}")
        return tuple(self.snr_db) * P if len(self.snr_db) == 1 else tuple(self.snr_db)


def build_scene(spec: RDMapsSpec, geometry, frames: int, frame_s: float,
                state_index: tuple[int, int, int, int]) -> MapScene:
    """The :class:`MapScene` of a case: ``spec``'s transmitters and receiver, or every pair of the
    recipe's ``geometry`` (a 2-D :class:`~pmsr_nn.geometry.Geometry`, sensors on the ground)."""
    if spec.transmitters:
        P = len(spec.transmitters)
        names = tuple(t.name for t in spec.transmitters)
        txp = _triples([t.position_m for t in spec.transmitters], "transmitter positions")
        txv = _triples([t.velocity_mps for t in spec.transmitters], "transmitter velocities")
        rxp = _triples([spec.receiver_m] * P, "rd_maps.receiver_m")
        lam = (spec.maps.wavelength,) * P
        snr = spec.snr_per_map(P, "one per listed transmitter")
    else:
        pairs = geometry.pairs
        P = len(pairs)
        ground = lambda pos: tuple(float(v) for v in pos) + (0.0,) * (3 - len(pos))
        names = tuple(f"tx{i + 1}-rx{j + 1}" for i, j in pairs)
        txp = tuple(ground(geometry.transmitters[i].position_m) for i, _ in pairs)
        txv = ((0.0, 0.0, 0.0),) * P
        rxp = tuple(ground(geometry.receivers[j].position_m) for _, j in pairs)
        own = spec.maps.wavelength
        lam = tuple(own if own is not None else 299_792_458.0 / geometry.transmitters[i].carrier_hz for i, _ in pairs)
        snr = spec.snr_per_map(P, "every transmitter-receiver pair of the recipe")
    return MapScene(names, txp, txv, rxp, lam, snr, spec.maps, spec.birth_box, frames, frame_s, spec.map_extent,
                    state_index)


@dataclass(frozen=True)
class TBDScene:
    """Satellites seen by a receiver at the origin, maps, SNRs (dB, one per satellite), frames and
    one target (planar CV at ``maps.altitude_m``: ``position_m`` / ``velocity_mps`` at
    ``appears_frame``). The maps' wavelength is ``maps``' or the seed's 0.19 m."""

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

    @cached_property
    def scene(self) -> MapScene:
        """The maps as a :class:`MapScene` (receiver at the origin)."""
        lam = self.maps.wavelength if self.maps.wavelength is not None else GNSS_WAVELENGTH_M
        P = len(self.satellites)
        return MapScene(tuple(s.name for s in self.satellites), tuple(tuple(s.position_m) for s in self.satellites),
                        tuple(tuple(s.velocity_mps) for s in self.satellites), ((0.0, 0.0, 0.0),) * P, (lam,) * P,
                        tuple(self.snr_db), self.maps, self.birth_box, self.frames, self.frame_s, self.map_extent)

    @property
    def P(self) -> int:
        return len(self.satellites)

    @property
    def grid(self) -> MapGrid:
        return self.scene.grid

    def cells(self, x: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        return self.scene.cells(x, k)

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


EXAMPLE_WINDOW = (15, 25)
"""Half-size (Doppler rows, range columns) of the map windows kept for the report's figure."""


@dataclass
class RangeDopplerMaps:
    """The ``rd_maps`` product of a block: ``frame(k)`` gives maps ``(B, P, D, U)`` complex64 of
    frame ``k`` (0-based); ``truth_x (B, K, N, 4)`` the targets' CV states (NaN while absent),
    ``present (K, N)``. ``select``: the runs this product hands out (:meth:`runs`); the maps are
    always drawn for the whole block, so a run's maps do not depend on which runs are asked for.
    ``moved_to``: the device the maps are handed on (:meth:`to`; ``None``: the truth's)."""

    scene: MapScene
    truth_x: torch.Tensor
    present: torch.Tensor
    seed: int
    select: slice | None = None
    moved_to: torch.device | None = None

    @property
    def B(self) -> int:
        return self.truth_x.shape[0] if self.select is None else self.truth_x[self.select].shape[0]

    @property
    def device(self) -> torch.device:
        """The device of the maps :meth:`frame` gives (a method's tensors follow it)."""
        return self.truth_x.device if self.moved_to is None else self.moved_to

    def to(self, device: torch.device | str) -> "RangeDopplerMaps":
        """The same product handing its maps on ``device``. They are still drawn where the truth is
        (the CPU, as every product's draws), so every device reads the same maps."""
        return dataclasses.replace(self, moved_to=torch.device(device))

    def frame(self, k: int) -> torch.Tensor:
        sc = self.scene
        x = torch.nan_to_num(self.truth_x[:, k])  # (B, N, 4); absent targets add nothing
        rng, dop = sc.range_doppler(x, k)  # (B, N, P)
        g = seeded_generator(self.seed, k, device=x.device)
        present = self.present[k].expand(x.shape[0], -1)
        snr = torch.tensor(sc.snr_db, dtype=torch.float64, device=x.device)
        maps = simulate_frame(rng.transpose(1, 2), dop.transpose(1, 2), present, snr, sc.grid, sc.maps, g)
        return (maps if self.select is None else maps[self.select]).to(self.device)

    def first_scans(self, W: int) -> "RangeDopplerMaps":
        """The maps of the first ``W`` frames (each frame's maps those of the whole product)."""
        W = min(W, self.scene.frames)
        return dataclasses.replace(self, scene=dataclasses.replace(self.scene, frames=W), truth_x=self.truth_x[:, :W],
                                   present=self.present[:W])

    def runs(self, i: slice) -> "RangeDopplerMaps":
        """The product of runs ``i`` of the block (a slice of the block's runs)."""
        if self.select is not None:
            raise ValueError("runs() of a product that is already a selection")
        return dataclasses.replace(self, select=i)

    def examples(self) -> dict:
        """Run 0's maps around the first target at three frames of its life (first, middle, next to
        last), for the report: per frame ``k`` (1-based) ``@rd_maps_power_f{k}`` ``(P, 2h+1, 2w+1)``
        (|z|^2 / noise power, NaN outside the map), ``@rd_maps_origin_f{k}`` ``(P, 2)`` the window's
        first (row, column) and ``@rd_maps_cells_f{k}`` ``(P, 2)`` the target's fractional cell."""
        alive = torch.nonzero(self.present[:, 0])[:, 0].tolist()
        if not alive:
            return {}
        first, last = alive[0], alive[-1]
        frames = sorted({first, (first + last + 2) // 2 - 1, max(last - 1, first)})  # 1-based: a, (a + d) // 2, d - 1
        h, w = EXAMPLE_WINDOW
        out = {}
        grid = self.scene.grid
        for k in frames:
            power = (self.frame(k)[0].abs() ** 2 / self.scene.maps.noise_power).to(torch.float64)  # (P, D, U)
            d, u = self.scene.cells(self.truth_x[0, k, 0], k)
            P = power.shape[0]
            win = torch.full((P, 2 * h + 1, 2 * w + 1), float("nan"), dtype=torch.float64)
            origin = torch.zeros(P, 2, dtype=torch.float64)
            for p in range(P):
                dc, uc = int(round(float(d[p]))), int(round(float(u[p])))
                r0, c0 = dc - h, uc - w
                rs, cs = max(r0, 0), max(c0, 0)
                re, ce = min(dc + h + 1, grid.D), min(uc + w + 1, grid.U)
                if re > rs and ce > cs:
                    win[p, rs - r0:re - r0, cs - c0:ce - c0] = power[p, rs:re, cs:ce]
                origin[p] = torch.tensor([r0, c0], dtype=torch.float64)
            out[f"@rd_maps_power_f{k + 1}"] = win.cpu().numpy()
            out[f"@rd_maps_origin_f{k + 1}"] = origin.cpu().numpy()
            out[f"@rd_maps_cells_f{k + 1}"] = torch.stack([d, u], -1).to(torch.float64).cpu().numpy()
        return out


def make_rd_maps(sensing: SensorSetup, truth: Truth, g: torch.Generator, g_prior: torch.Generator) -> RangeDopplerMaps:
    """The product from the truth: one 62-bit seed drawn from ``g`` names the block's maps."""
    seed = int(torch.randint(0, 2**62, (1,), generator=g))
    scene = sensing.rd_maps
    return RangeDopplerMaps(scene, scene.cv_states(truth.x), truth.alive, seed)
