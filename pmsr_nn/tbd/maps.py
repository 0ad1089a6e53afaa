"""Range-Doppler maps of a GNSS-based multistatic passive radar: geometry, response, simulation.

Moving satellites as transmitters seen by one receiver (the Remote Sensing 2020 seed, ``001``),
or fixed transmitters with receivers anywhere (a scenario's FM pairs): per transmitter-receiver
pair and frame the receiver forms a map after 2-D coherent integration; the seed removes the
direct path's range and the transmitter's own Doppler, so a map's axes are

* the *excess* bistatic range ``R = |p - p_T| + |p - p_R| - |p_T - p_R|`` (m), and
* the target's Doppler ``f = -(u_T + u_R) . v / lambda`` (Hz), ``u_T``, ``u_R`` the unit vectors
  from transmitter and receiver to the target, ``v`` its velocity (the transmitter's motion removed).

Response (our choice, the seed's Eq. 3 being the modified-RFT output): separable, with a *triangle*
in range, the autocorrelation envelope of a C/A-like code (half-width one chip, ``c / chip_rate_hz``
of path length) and a *sinc* in Doppler, the response of a rectangular coherent frame whose
Doppler resolution is the cell ``doppler_cell_hz``. A target of complex amplitude ``A exp(j phi)``
(phase uniform per frame and map, amplitude fixed: Swerling 0) adds
``A exp(j phi) tri((R_u - R) / chip) sinc((f_d - f) / doppler_cell)`` to cell ``(d, u)``, in circular
complex Gaussian noise of power ``noise_power`` per cell; the map SNR is ``A^2 / noise_power``
(the seed's Eq. 25). Range cells are ``c / sample_rate_hz`` (60 m at the seed's 5 MHz). Several
targets add their responses, each with its own phase per frame and map.

Shapes: maps ``(B, P, D, U)`` complex64 (runs, transmitters, Doppler rows, range columns); a
map's first cell is at ``range0_m[p]``, ``doppler0_hz[p]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..config import require
from ..measurements import MIN_SENSOR_DISTANCE_M

C = 299_792_458.0
"""Speed of light (m/s)."""


@dataclass(frozen=True)
class Satellite:
    """A transmitter: ``position_m`` and ``velocity_mps`` (3 values each) at time 0."""

    name: str
    position_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]

    def __post_init__(self) -> None:
        require(len(self.position_m) == 3 and len(self.velocity_mps) == 3
                and all(math.isfinite(v) for v in (*self.position_m, *self.velocity_mps)),
                f"satellite {self.name!r}: position_m and velocity_mps must be 3 finite values each")


@dataclass(frozen=True)
class MapSpec:
    """How maps are formed. ``sample_rate_hz`` sets the range cell (``c / fs``), ``chip_rate_hz``
    the triangle's half-width (defaults: the seed's 5 MHz and C/A code's 1.023 MHz); or
    ``bandwidth_hz`` ``B`` sets both, for a signal of that bandwidth (a DVB-T channel's 7.6 MHz: a
    half-width ``c / B`` of 39 m and cells of ``c / 2B``, 20 m; an FM channel's 100 kHz: 3 km and
    1.5 km); ``doppler_cell_hz`` the Doppler cell (the inverse of the coherent
    frame); the carrier is ``wavelength_m`` or ``carrier_hz`` (at most one; neither: each
    transmitter's own carrier, which a scenario's FM transmitters have and satellites have not);
    ``noise_power`` per cell; ``altitude_m``: the target's (known, constant) height above the
    ground the sensors stand on; ``margin_cells``: cells added on every side of the region the
    birth box can reach."""

    wavelength_m: float | None = None
    sample_rate_hz: float | None = None
    chip_rate_hz: float | None = None
    doppler_cell_hz: float = 0.5
    noise_power: float = 1.0
    altitude_m: float = 5000.0
    margin_cells: int = 8
    carrier_hz: float | None = None
    bandwidth_hz: float | None = None

    def __post_init__(self) -> None:
        B = self.bandwidth_hz
        require(B is None or (math.isfinite(B) and B > 0), f"maps.bandwidth_hz must be positive (or null), got {B}")
        fs, chip = (5.0e6, 1.023e6) if B is None else (2 * B, B)
        # with a bandwidth, the two rates it sets may be given only as it sets them (a recorded spec reloads)
        require(B is None or all(v is None or math.isclose(v, w) for v, w in ((self.sample_rate_hz, fs),
                                                                              (self.chip_rate_hz, chip))),
                "maps: give bandwidth_hz, or sample_rate_hz and chip_rate_hz, not both")
        object.__setattr__(self, "sample_rate_hz", fs if self.sample_rate_hz is None else self.sample_rate_hz)
        object.__setattr__(self, "chip_rate_hz", chip if self.chip_rate_hz is None else self.chip_rate_hz)
        for name in ("sample_rate_hz", "chip_rate_hz", "doppler_cell_hz", "noise_power"):
            v = getattr(self, name)
            require(math.isfinite(v) and v > 0, f"maps.{name} must be positive, got {v}")
        for name in ("wavelength_m", "carrier_hz"):
            v = getattr(self, name)
            require(v is None or (math.isfinite(v) and v > 0), f"maps.{name} must be positive (or null), got {v}")
        require(self.wavelength_m is None or self.carrier_hz is None,
                "maps: give wavelength_m or carrier_hz, not both")
        require(math.isfinite(self.altitude_m) and self.altitude_m >= 0, "maps.altitude_m must be >= 0")
        require(self.margin_cells >= 0, "maps.margin_cells must be >= 0")

    @property
    def wavelength(self) -> float | None:
        """The maps' carrier wavelength (m): ``wavelength_m``, or ``c / carrier_hz``; None where each
        transmitter's own carrier sets it."""
        if self.carrier_hz is not None:
            return C / self.carrier_hz
        return self.wavelength_m

    @property
    def range_cell_m(self) -> float:
        return C / self.sample_rate_hz

    @property
    def lobe_cells(self) -> float:
        """Half-width of the range triangle in range cells (``fs / chip rate``)."""
        return self.sample_rate_hz / self.chip_rate_hz


def transmitter_positions(satellites: tuple[Satellite, ...], times_s: torch.Tensor) -> torch.Tensor:
    """Satellite positions ``(K, P, 3)`` at ``times_s (K,)`` (straight lines over the short scene)."""
    p0 = torch.tensor([s.position_m for s in satellites], dtype=torch.float64)
    v = torch.tensor([s.velocity_mps for s in satellites], dtype=torch.float64)
    return p0 + times_s[:, None, None] * v


def range_doppler(states: torch.Tensor, tx: torch.Tensor, spec: MapSpec, rx: torch.Tensor | None = None,
                  wavelength: torch.Tensor | float | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Excess bistatic range (m) and target Doppler (Hz) of planar CV states ``(..., 4)``
    ``[x, vx, y, vy]`` at altitude ``spec.altitude_m``, for transmitters ``tx (P, 3)`` and
    receivers ``rx (P, 3)`` (one per map; ``None``: every map's at the origin): each ``(..., P)``.
    ``wavelength``: per map ``(P,)`` or one value (``None``: ``spec.wavelength``).

    Everything is computed relative to each map's receiver (``q = p - r``, ``s = t - r``, exact
    for a receiver at the origin), and the excess range as ``(|q|^2 - 2 q.s) / (|q - s| + |s|) + |q|``,
    the identity ``|q - s| - |s| = (|q|^2 - 2 q.s) / (|q - s| + |s|)`` without the cancellation
    between two 20,000 km distances that the direct form ``|q - s| + |q| - |s|`` suffers."""
    x, vx, y, vy = states.unbind(-1)
    pos = torch.stack([x, y, torch.full_like(x, spec.altitude_m)], -1)  # (..., 3)
    vel = torch.stack([vx, vy, torch.zeros_like(vx)], -1)
    if rx is None:
        rx = torch.zeros(1, 3, dtype=tx.dtype, device=tx.device)
    q = pos[..., None, :] - rx.to(pos.dtype)  # (..., P, 3): the target from each map's receiver
    s = (tx.to(torch.float64) - rx.to(torch.float64)).to(tx.dtype)  # (P, 3): each transmitter from its receiver
    d_t = (q - s).norm(dim=-1)
    d_r = q.norm(dim=-1)
    rng = (d_r * d_r - 2 * (q * s).sum(-1)) / (d_t + s.norm(dim=-1)) + d_r
    # the bistatic range rate v . (u_T + u_R), unit vectors guarded as measurements.bistatic_range_rate's
    diff_t = q - s
    u_t = diff_t / torch.linalg.vector_norm(diff_t, dim=-1).clamp_min(MIN_SENSOR_DISTANCE_M).unsqueeze(-1)
    u_r = q / torch.linalg.vector_norm(q, dim=-1).clamp_min(MIN_SENSOR_DISTANCE_M).unsqueeze(-1)
    rate = ((u_t + u_r) * vel.unsqueeze(-2)).sum(-1)
    lam = spec.wavelength if wavelength is None else wavelength
    if lam is None:
        raise ValueError("range_doppler: no wavelength (give maps.wavelength_m or carrier_hz, or per-map wavelengths)")
    if isinstance(lam, torch.Tensor):
        lam = lam.to(rate.device, rate.dtype)
    return rng, -rate / lam


@dataclass(frozen=True)
class MapGrid:
    """The cells of each transmitter's map: first cell ``range0_m (P,)``, ``doppler0_hz (P,)``;
    ``D`` Doppler rows and ``U`` range columns (the same for every map, so maps stack)."""

    range0_m: torch.Tensor
    doppler0_hz: torch.Tensor
    D: int
    U: int
    range_cell_m: float
    doppler_cell_hz: float
    reach_cells: tuple[torch.Tensor, torch.Tensor] | None = None
    """Per map ``(P,)``: how many Doppler and range cells the surveillance area (what the birth box
    reaches) spans, margins aside (:func:`grid_covering`'s grid; None for a grid given by hand)."""

    def cell_coordinates(self, rng: torch.Tensor, dop: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Fractional (Doppler row, range column) of ranges / Dopplers ``(..., P)``."""
        return (dop - self.doppler0_hz) / self.doppler_cell_hz, (rng - self.range0_m) / self.range_cell_m

    def axes(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        """Doppler (Hz) and excess range (m) of map ``p``'s rows and columns."""
        return (float(self.doppler0_hz[p]) + self.doppler_cell_hz * np.arange(self.D),
                float(self.range0_m[p]) + self.range_cell_m * np.arange(self.U))


def grid_covering(box_lo: torch.Tensor, box_hi: torch.Tensor, tx: torch.Tensor, dt: float, spec: MapSpec,
                  samples: int = 7, rx: torch.Tensor | None = None,
                  wavelength: torch.Tensor | float | None = None) -> MapGrid:
    """The smallest grid holding every state a birth at any frame can reach at any later frame:
    the box ``[box_lo, box_hi]`` (``(4,)``, CV ``[x, vx, y, vy]``) moved straight for ``0 .. K-1``
    frames of ``dt`` s, seen from the transmitters ``tx (K, P, 3)`` of the frame it reaches (and
    the receivers ``rx``, wavelengths ``wavelength``: :func:`range_doppler`'s), plus the margin
    (range and Doppler are smooth over the box, sampled on ``samples`` points per axis)."""
    axes = [torch.linspace(float(a), float(b), samples, dtype=torch.float64) for a, b in zip(box_lo, box_hi)]
    pts = torch.cartesian_prod(*axes)  # (S, 4)
    K = tx.shape[0]
    r_lo = r_hi = f_lo = f_hi = None
    # fixed transmitters: the last frame's lags 0 .. K-1 hold every earlier frame's (K frames, not K^2 / 2)
    frames = [K - 1] if bool((tx == tx[:1]).all()) else range(K)
    for k in frames:
        lag = torch.arange(k + 1, dtype=torch.float64)[:, None] * dt  # born k, k-1, .., 0 frames ago
        moved = pts[None].clone().repeat(k + 1, 1, 1)
        moved[..., 0] += lag * moved[..., 1]
        moved[..., 2] += lag * moved[..., 3]
        rng, dop = range_doppler(moved.reshape(-1, 4), tx[k], spec, rx, wavelength)  # (S', P)
        lows = (rng.amin(0), dop.amin(0))
        highs = (rng.amax(0), dop.amax(0))
        if r_lo is None:
            (r_lo, f_lo), (r_hi, f_hi) = lows, highs
        else:
            r_lo, f_lo = torch.minimum(r_lo, lows[0]), torch.minimum(f_lo, lows[1])
            r_hi, f_hi = torch.maximum(r_hi, highs[0]), torch.maximum(f_hi, highs[1])
    dr, df = spec.range_cell_m, spec.doppler_cell_hz
    pad_r = (spec.margin_cells + math.ceil(spec.lobe_cells)) * dr
    pad_f = (spec.margin_cells + 1) * df
    r0, f0 = r_lo - pad_r, f_lo - pad_f
    U = int(math.ceil(float(((r_hi + pad_r - r0) / dr).max()))) + 1
    D = int(math.ceil(float(((f_hi + pad_f - f0) / df).max()))) + 1
    return MapGrid(r0, f0, D, U, dr, df, ((f_hi - f_lo) / df, (r_hi - r_lo) / dr))


def triangle(x: torch.Tensor) -> torch.Tensor:
    return (1.0 - x.abs()).clamp(min=0.0)


def response(d_rows: torch.Tensor, u_cols: torch.Tensor, d: torch.Tensor, u: torch.Tensor, lobe_cells: float):
    """Unit-amplitude response ``tri((u_cols - u) / lobe) sinc(d_rows - d)`` of targets at fractional
    cells ``(d, u)`` on cells ``(d_rows, u_cols)`` (broadcast): real, signed (the sinc's sidelobes
    alternate)."""
    return triangle((u_cols - u) / lobe_cells) * torch.sinc(d_rows - d)


def simulate_frame(rng: torch.Tensor, dop: torch.Tensor, present: torch.Tensor, snr_db: torch.Tensor, grid: MapGrid,
                   spec: MapSpec, g: torch.Generator) -> torch.Tensor:
    """One frame's maps ``(B, P, D, U)`` complex64: noise of power ``spec.noise_power`` plus each
    target present: target ``n`` at ``rng``, ``dop (B, P, N)`` where ``present (B, N)`` (or one
    target: ``(B, P)`` and ``(B,)``) with map SNR ``snr_db (P,)`` and a uniform random phase per
    run, map and target (:func:`frame_at_cells`)."""
    if rng.dim() == 2:
        rng, dop, present = rng[..., None], dop[..., None], present[:, None]
    amp = torch.sqrt(spec.noise_power * 10.0 ** (snr_db.to(torch.float64) / 10))  # (P,)
    d, u = grid.cell_coordinates(rng.transpose(1, 2), dop.transpose(1, 2))  # (B, N, P)
    return frame_at_cells(d, u, present, amp, (grid.D, grid.U), spec.noise_power, spec.lobe_cells, g)


def frame_at_cells(d: torch.Tensor, u: torch.Tensor, present: torch.Tensor, amplitude: torch.Tensor,
                   size: tuple[int, int], noise_power: float, lobe_cells: float, g: torch.Generator) -> torch.Tensor:
    """Maps ``(B, P, D, U)`` complex64 of ``size = (D, U)`` cells: noise of power ``noise_power``
    plus target ``n`` at fractional cells ``d, u (B, N, P)`` where ``present (B, N)``, of amplitude
    ``amplitude`` (``(P,)`` or ``(B, P)``), range lobe half-width ``lobe_cells``, and a uniform
    random phase per run, map and target. Noise is drawn first, then the phases ``(B, P, N)``, in
    that order always; the responses are summed in complex128 (target by target) and added to the
    noise in complex64."""
    B, N, P = d.shape
    D, U = size
    s = math.sqrt(noise_power / 2)
    dev = d.device  # the draws too: ``g`` is a generator of this device
    noise = torch.randn((B, P, D, U, 2), generator=g, dtype=torch.float32, device=dev) * s
    maps = torch.view_as_complex(noise)
    phase = torch.rand((B, P, N), generator=g, dtype=torch.float64, device=dev) * (2 * math.pi)
    rows = torch.arange(D, dtype=torch.float64, device=dev)
    cols = torch.arange(U, dtype=torch.float64, device=dev)
    sig = None
    zero = torch.zeros((), dtype=torch.complex128, device=dev)
    for n in range(N):
        # separable: (B, P, D, 1) x (B, P, 1, U)
        dr = torch.sinc(rows - d[:, n, :, None])
        ur = triangle((cols - u[:, n, :, None]) / lobe_cells)
        c = amplitude * torch.polar(torch.ones_like(phase[..., n]), phase[..., n])  # (B, P)
        term = torch.where(present[:, n, None, None, None], c[..., None, None] * dr[..., :, None] * ur[..., None, :], zero)
        sig = term if sig is None else sig + term
    return maps + sig.to(torch.complex64)


def power_ratio(half: int | None, lobe_cells: float, points: int = 2001) -> float:
    """Expected share of a target's map energy inside the ``(2 half + 1)^2`` sub-area centred on the
    cell nearest to it (``None``: the whole, unbounded map, 1), for the triangle x sinc response with
    the target's sub-cell offsets uniform in both axes: ``E_u[sum_{|n|<=h} tri^2((n-u)/L)] /
    E_u[sum_n tri^2((n-u)/L)]`` times the same for sinc^2 (whose sum over all cells is 1 for any
    offset). Midpoint quadrature over the offsets; the sums run over every cell the lobes reach
    (sinc^2: +-20,000 cells, its neglected tail ~1e-5 of the energy)."""
    if half is None:
        return 1.0
    off = (torch.arange(points, dtype=torch.float64) + 0.5) / points - 0.5  # offsets in [-1/2, 1/2)
    n_r = torch.arange(-math.ceil(lobe_cells) - half - 1, math.ceil(lobe_cells) + half + 2, dtype=torch.float64)
    tri2 = triangle((n_r[None] - off[:, None]) / lobe_cells) ** 2  # (offsets, cells)
    inner_r = tri2[:, n_r.abs() <= half].sum(1).mean() / tri2.sum(1).mean()
    n_d = torch.arange(-half, half + 1, dtype=torch.float64)
    inner_d = (torch.sinc(n_d[None] - off[:, None]) ** 2).sum(1).mean()
    return float(inner_r * inner_d)
