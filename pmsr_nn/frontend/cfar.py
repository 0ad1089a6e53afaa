"""Two-dimensional order-statistic CFAR (Rohling 1983) on range-Doppler power maps.

A range-Doppler map ``power (..., D, U)`` is the square-law output |2D-CCF|^2: Doppler rows (``D``
bins, increasing frequency), range columns (``U`` bins, delay ``0 .. U-1``); leading dimensions
are a batch of maps (Monte Carlo runs x transmitter pairs). In noise only a cell's power is
exponential (complex Gaussian amplitude) with a mean that may drift slowly over the map.

For every cell under test (CUT) the training cells are the rectangle of half-widths
``g + t`` (Doppler, range) around it minus the guard rectangle of half-widths ``g`` (which holds
the CUT and the main lobe of a target in it). The noise level is read from the ``k``-th smallest
training power ``X_(k)``, and the CUT is a detection when ``power > alpha * X_(k)``. Unlike a
cell-averaging CFAR, one or a few strong targets among the training cells only move ``X_(k)`` by a
few ranks, so targets a few cells apart do not mask each other (the reason for the order statistic).

For ``N`` i.i.d. exponential training cells the false-alarm probability (Eq. 2 of the Daniyan et
al. seed) is ``P_FA = N! (alpha + N - k)! / ((N - k)! (alpha + N)!) = prod_{i<k} (N - i) / (N - i + alpha)``,
whatever the noise mean; :func:`os_cfar_alpha` solves it for ``alpha`` (real, so the factorials are
Gamma functions), so that ``alpha`` follows from ``(N, k, pfa)`` and is never tuned.

Where the window leaves the map only the training cells that exist are used: such a cell has its
own ``N``, ``k = ceil(rank N)`` and ``alpha``, so its false-alarm probability is the nominal one as
well. With ``wrap_doppler=True`` the Doppler axis is circular (the full Doppler FFT of the
batches 2D-CCF is), and only the range edges are cut.

Speed: the ``N`` training powers of every cell are copied into a ``(cells, N)`` block (a chunk of
Doppler rows at a time, so it stays in cache) and the order statistic is selected in place
(``numpy.partition`` on the CPU, in as many threads as torch uses: about twice as fast as
``torch.kthvalue`` there; ``torch.kthvalue`` on other devices). Cut windows get the same ``K`` as
full ones: ``K - k`` of their missing cells are set to -inf and the rest are NaN (sorted last), so
the ``K``-th value is their own ``k``-th and one selection serves every cell. On this project's
2-core CPU a batch of six 400 x 52 maps with the default window (216 training cells, 27e6 values
to copy and select) takes 60-110 ms, 10-18 ms per map, in float32 or float64 (copying and
selecting cost about the same). When only the detections and their noise levels are wanted,
``full_maps=False`` counts instead of selecting: 16-30 ms for the six maps, 3-5 ms per map.
"""

from __future__ import annotations

import functools
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch
from numpy.lib.stride_tricks import sliding_window_view
from scipy.optimize import brentq

from ..config import require


@dataclass(frozen=True)
class CfarResult:
    """Output of :func:`os_cfar` for maps ``power (..., D, U)``.

    ``detections (..., D, U)`` bool: ``power > threshold``. ``threshold (..., D, U)``: ``alpha *
    X_(k)``, power units. ``noise (..., D, U)``: unbiased estimate of the mean noise power of the
    cell, ``X_(k) / sum_{i<k} 1/(N - i)`` (the mean of the ``k``-th of ``N`` unit exponentials), power
    units; this, not ``X_(k)`` itself, is what SNRs are referred to. ``alpha (D, U)``, ``n_train
    (D, U)`` and ``k (D, U)``: the scale factor, the number of training cells and the rank used at
    each cell (the same for every map; they differ from the interior values only at cut windows).
    With ``os_cfar(..., full_maps=False)``, ``threshold`` and ``noise`` are NaN off the detections.
    """

    detections: torch.Tensor
    threshold: torch.Tensor
    noise: torch.Tensor
    alpha: torch.Tensor
    n_train: torch.Tensor
    k: torch.Tensor


def os_cfar_alpha(n_train, k, pfa: float):
    """Scale factor ``alpha`` of an OS-CFAR with ``n_train`` training cells and rank ``k`` (the
    ``k``-th smallest) for false-alarm probability ``pfa`` in i.i.d. exponential noise.

    Solves ``prod_{i<k} (N - i) / (N - i + alpha) = pfa`` (Eq. 2 of the seed in Gamma-function form)
    with Brent's method on the logarithm, bracketed by ``(N - k + 1) x <= alpha <= N x``,
    ``x = pfa^(-1/k) - 1`` (each factor lies between ``1 / (1 + alpha / (N - k + 1))`` and
    ``1 / (1 + alpha / N)``); ``k = 1`` has the closed form ``N (1/pfa - 1)``. ``n_train`` and ``k``
    may be arrays (broadcast); each distinct ``(N, k, pfa)`` is solved once and cached. Returns a
    float for scalar input, else a float64 array.
    """
    require(isinstance(pfa, (int, float)) and 0.0 < pfa < 1.0, f"CFAR pfa must be in (0, 1), got {pfa}")
    n_arr, k_arr = np.broadcast_arrays(np.asarray(n_train), np.asarray(k))
    require(np.issubdtype(n_arr.dtype, np.integer) and np.issubdtype(k_arr.dtype, np.integer),
            f"CFAR n_train and k must be whole numbers, got {n_train} and {k}")
    require(bool(np.all(k_arr >= 1)) and bool(np.all(k_arr <= n_arr)),
            f"CFAR rank k must lie in [1, n_train], got k={k} for n_train={n_train}")
    out = np.array([_alpha(int(n), int(j), float(pfa)) for n, j in zip(n_arr.ravel(), k_arr.ravel())],
                   dtype=np.float64).reshape(n_arr.shape)
    return float(out) if out.ndim == 0 else out


@functools.lru_cache(maxsize=4096)
def _alpha(n: int, k: int, pfa: float) -> float:
    if k == 1:
        return n * (1.0 / pfa - 1.0)
    d = n - np.arange(k, dtype=np.float64)
    log_pfa = math.log(pfa)

    def excess(a: float) -> float:  # log(1/P_FA(a)) + log(pfa): increasing, 0 at the solution
        return float(np.log1p(a / d).sum()) + log_pfa

    x = math.expm1(-log_pfa / k)
    lo, hi = (n - k + 1) * x * (1 - 1e-9), n * x * (1 + 1e-9)  # margins for rounding only
    return float(brentq(excess, lo, hi, xtol=1e-300, rtol=4 * np.finfo(float).eps, maxiter=200))


@dataclass(frozen=True)
class _Layout:
    """Window geometry of one (map size, guard, train, rank, pfa, wrap) setting, per cell ``(D, U)``."""

    n: np.ndarray          # training cells that exist
    k: np.ndarray          # rank used
    alpha: np.ndarray      # scale factor for (n, k, pfa)
    scale: np.ndarray      # sum_{i<k} 1 / (n - i): E[X_(k)] / noise mean
    n_full: int
    k_full: int
    # cut windows: training slot ``pos`` of cell (row, col) is set to -inf (K - k slots per cell,
    # sorted by row), so that the K-th value of the window is its own k-th
    cut_row: np.ndarray
    cut_col: np.ndarray
    cut_pos: np.ndarray


def _valid_span(length: int, half: int, wrap: bool) -> np.ndarray:
    """How many of the ``2 half + 1`` positions centred on each index exist on an axis of ``length``."""
    if wrap:
        return np.full(length, 2 * half + 1, dtype=np.int64)
    i = np.arange(length)
    return np.minimum(i + half, length - 1) - np.maximum(i - half, 0) + 1


@functools.lru_cache(maxsize=32)
def _layout(D: int, U: int, guard: tuple[int, int], train: tuple[int, int], rank, pfa: float, wrap: bool) -> _Layout:
    (gd, gr), (td, tr) = guard, train
    Rd, Rr = gd + td, gr + tr
    n = (_valid_span(D, Rd, wrap)[:, None] * _valid_span(U, Rr, False)[None, :]
         - _valid_span(D, gd, wrap)[:, None] * _valid_span(U, gr, False)[None, :])
    n_full = (2 * Rd + 1) * (2 * Rr + 1) - (2 * gd + 1) * (2 * gr + 1)
    k_full = _rank(rank, n_full, n_full)
    k = _rank(rank, n, n_full)
    pairs, inverse = np.unique(np.stack([n.ravel(), k.ravel()], axis=1), axis=0, return_inverse=True)
    alpha = os_cfar_alpha(pairs[:, 0], pairs[:, 1], pfa)[inverse.ravel()].reshape(D, U)
    harmonic = np.concatenate([[0.0], np.cumsum(1.0 / np.arange(1, n_full + 1))])
    scale = harmonic[n] - harmonic[n - k]
    sentinels = k_full - k  # 0 <= K - k <= N_full - n: ceil(r a) - ceil(r b) <= ceil(r (a - b)) <= a - b
    cd, cu = np.nonzero(sentinels)
    offsets = _ring_offsets(guard, train)
    dd, uu = cd[:, None] + offsets[:, 0], cu[:, None] + offsets[:, 1]
    missing = ~((uu >= 0) & (uu < U) & (wrap | ((dd >= 0) & (dd < D))))
    cell, pos = np.nonzero(missing & (np.cumsum(missing, axis=1) <= sentinels[cd, cu][:, None]))
    return _Layout(n, k, alpha, scale, n_full, int(k_full), cd[cell], cu[cell], pos)


def _rank(rank, n, n_full: int):
    """``k`` for ``n`` training cells: ``ceil(rank n)`` for a fraction, or an integer rank of a full
    window scaled to a cut one, ``ceil(rank n / n_full)``; at least 1."""
    n = np.asarray(n)
    if isinstance(rank, int):
        k = (rank * n + n_full - 1) // n_full
    else:
        k = np.ceil(np.round(rank * n, 9)).astype(np.int64)
    return np.maximum(k, 1)


def _check(power: torch.Tensor, guard, train, rank, pfa) -> tuple[tuple[int, int], tuple[int, int]]:
    def pair(name, value) -> tuple[int, int]:
        ok = (isinstance(value, (tuple, list)) and len(value) == 2
              and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0 for v in value))
        require(ok, f"CFAR {name} must be a pair (Doppler, range) of non-negative whole numbers of bins, got {value!r}")
        return int(value[0]), int(value[1])

    guard, train = pair("guard", guard), pair("train", train)
    require(train != (0, 0), "CFAR train = (0, 0) leaves no training cells")
    require(isinstance(pfa, (int, float)) and not isinstance(pfa, bool) and 0.0 < pfa < 1.0,
            f"CFAR pfa must be in (0, 1), got {pfa}")
    if isinstance(rank, (int, np.integer)) and not isinstance(rank, bool):
        require(rank >= 1, f"CFAR rank must be a fraction in (0, 1] or a whole number >= 1, got {rank}")
    else:
        require(isinstance(rank, float) and 0.0 < rank <= 1.0,
                f"CFAR rank must be a fraction in (0, 1] or a whole number >= 1, got {rank!r}")
    require(isinstance(power, torch.Tensor) and power.dim() >= 2,
            f"CFAR power must be a tensor (..., Doppler, range), got {_describe(power)}")
    require(power.is_floating_point(), f"CFAR power must be a real power map |CCF|^2, got dtype {power.dtype}")
    D, U = power.shape[-2:]
    for axis, g, t, size in (("Doppler", guard[0], train[0], D), ("range", guard[1], train[1], U)):
        w = 2 * (g + t) + 1
        require(w <= size, f"CFAR window 2*(g+t)+1 = {w} {axis} bins exceeds the map's {size}")
    n_full = (2 * (guard[0] + train[0]) + 1) * (2 * (guard[1] + train[1]) + 1) - (2 * guard[0] + 1) * (2 * guard[1] + 1)
    if not isinstance(rank, float):
        require(rank <= n_full, f"CFAR rank {rank} exceeds the window's {n_full} training cells")
    if power.numel():
        require(bool(torch.isfinite(power).all()), "CFAR power must be finite (a |CCF|^2 map has no NaN or inf)")
        require(bool((power >= 0).all()), "CFAR power must be non-negative (a |CCF|^2 map)")
    return guard, train


def _describe(x) -> str:
    return f"shape {tuple(x.shape)}" if isinstance(x, torch.Tensor) else type(x).__name__


def os_cfar(power: torch.Tensor, guard: tuple[int, int] = (2, 1), train: tuple[int, int] = (8, 4),
            rank: float | int = 0.75, pfa: float = 1e-4, wrap_doppler: bool = False,
            full_maps: bool = True, alpha_factor: float = 1.0) -> CfarResult:
    """2-D OS-CFAR of maps ``power (..., D, U)`` (square-law power, Doppler rows, range columns).

    ``guard = (g_doppler, g_range)`` and ``train = (t_doppler, t_range)`` are half-widths in bins:
    the training cells of a CUT are the ``(2(g+t)+1)`` x ``(2(g+t)+1)`` rectangle around it minus the
    ``(2g+1)`` x ``(2g+1)`` guard rectangle (the defaults give 21 x 11 - 5 x 3 = 216 cells, a window
    of +-10 Hz and +-5 range bins for 1 Hz / 937 m bins, with the target's main lobe of +-1 bin
    inside the guard). ``rank``: a fraction of ``N`` (``k = ceil(rank N)``, at least 1) or a whole
    ``k`` for a full window (scaled to ``ceil(k N / N_full)`` where the window is cut). ``pfa``:
    false-alarm probability per cell in i.i.d. exponential noise. ``wrap_doppler``: circular
    Doppler axis. Returns a :class:`CfarResult` (``threshold`` and ``noise`` in ``power``'s dtype
    and device). Raises :class:`~pmsr_nn.errors.ConfigError` on a window larger than the map,
    ``pfa`` outside (0, 1), a bad ``rank``, negative guard/train, or a non-finite or negative map.

    ``full_maps=False`` (CPU only; elsewhere it only masks the full result) gives the same
    detections about 4x faster, with ``threshold`` and ``noise`` at the detections only (NaN
    elsewhere, which is all :func:`~pmsr_nn.frontend.centroid.centroids` reads): ``power > alpha
    X_(k)`` holds exactly when at least ``k`` training powers lie below ``power / alpha``, which is
    counted with one comparison per training cell and no copy or selection; the cells that pass
    (with a relative margin for rounding) then get their ``X_(k)`` by sorting their own windows, and
    the decision is made with the same arithmetic as the full path.

    ``alpha_factor`` (> 0) multiplies every cell's ``alpha``: 1 is Eq. 2 (i.i.d. cells); maps whose
    noise cells are correlated (an FM reference along range) need the factor of
    :func:`calibrate_alpha_factor` to keep ``pfa``.
    """
    guard, train = _check(power, guard, train, rank, pfa)
    require(isinstance(alpha_factor, (int, float)) and not isinstance(alpha_factor, bool)
            and math.isfinite(alpha_factor) and alpha_factor > 0, f"CFAR alpha_factor must be positive, got {alpha_factor!r}")
    D, U = power.shape[-2:]
    rank = float(rank) if isinstance(rank, float) else int(rank)
    lay = _layout(int(D), int(U), guard, train, rank, float(pfa), bool(wrap_doppler))
    maps = power.detach().reshape(-1, D, U)
    if maps.dtype not in (torch.float32, torch.float64):
        maps = maps.float()  # half precisions: select in float32 (numpy has no bfloat16)
    dev = power.device
    alpha = torch.tensor(lay.alpha * float(alpha_factor), device=dev)  # copies: the layout is cached
    scale = torch.tensor(lay.scale, device=dev)
    common = dict(alpha=alpha, n_train=torch.tensor(lay.n, device=dev), k=torch.tensor(lay.k, device=dev))
    if not full_maps and dev.type == "cpu":
        margin = 1.0 + 4 * torch.finfo(power.dtype).eps + 1e-12  # candidates: a superset of the detections
        b, d, u, xk = _kth_of_candidates(maps.numpy(), lay, alpha.numpy(), guard, train, wrap_doppler, margin)
        b, d, u, xk = (torch.from_numpy(a) for a in (b, d, u, xk))
        thr = (alpha[d, u] * xk).to(power.dtype)
        hit = maps.to(power.dtype)[b, d, u] > thr
        b, d, u, xk, thr = b[hit], d[hit], u[hit], xk[hit], thr[hit]
        threshold = torch.full((maps.shape[0], D, U), float("nan"), dtype=power.dtype, device=dev)
        threshold[b, d, u] = thr
        noise = torch.full_like(threshold, float("nan"))
        noise[b, d, u] = (xk / scale[d, u]).to(power.dtype)
        detections = torch.zeros(threshold.shape, dtype=torch.bool, device=dev)
        detections[b, d, u] = True
        return CfarResult(detections=detections.reshape(power.shape), threshold=threshold.reshape(power.shape),
                          noise=noise.reshape(power.shape), **common)
    if dev.type == "cpu":
        xk = torch.from_numpy(_kth_numpy(maps.numpy(), lay, guard, train, wrap_doppler))
    else:
        xk = _kth_torch(maps, lay, guard, train, wrap_doppler)
    xk = xk.reshape(power.shape)
    threshold = (alpha * xk).to(power.dtype)
    noise = (xk / scale).to(power.dtype)
    detections = power.detach() > threshold
    if not full_maps:
        threshold, noise = threshold.masked_fill(~detections, float("nan")), noise.masked_fill(~detections, float("nan"))
    return CfarResult(detections=detections, threshold=threshold, noise=noise, **common)


def _ring(guard: tuple[int, int], train: tuple[int, int]) -> list[tuple[slice, slice]]:
    """The training ring of a ``(Wd, Wr)`` window as four rectangles (top, bottom, left, right);
    their cells in this order, row-major within each, are the training slots ``0 .. N-1``."""
    (gd, gr), (td, tr) = guard, train
    Wd, Wr = 2 * (gd + td) + 1, 2 * (gr + tr) + 1
    mid = slice(td, td + 2 * gd + 1)
    parts = [(slice(0, td), slice(0, Wr)), (slice(Wd - td, Wd), slice(0, Wr)),
             (mid, slice(0, tr)), (mid, slice(Wr - tr, Wr))]
    return [(r, c) for r, c in parts if r.stop > r.start and c.stop > c.start]


def _ring_offsets(guard: tuple[int, int], train: tuple[int, int]) -> np.ndarray:
    """``(N, 2)`` (Doppler, range) offsets of the training slots from the CUT."""
    rows, cols = zip(*[np.meshgrid(np.arange(r.start, r.stop), np.arange(c.start, c.stop), indexing="ij")
                       for r, c in _ring(guard, train)])
    centre = (guard[0] + train[0], guard[1] + train[1])
    return np.stack([np.concatenate([r.ravel() for r in rows]) - centre[0],
                     np.concatenate([c.ravel() for c in cols]) - centre[1]], axis=1)


def _padded(maps: np.ndarray, Rd: int, Rr: int, wrap: bool) -> np.ndarray:
    """``maps (B, D, U)`` padded by ``Rd`` rows (circularly when ``wrap``, else NaN) and ``Rr`` NaN columns."""
    out = np.pad(maps, ((0, 0), (0, 0), (Rr, Rr)), constant_values=np.nan)
    if wrap:
        return np.pad(out, ((0, 0), (Rd, Rd), (0, 0)), mode="wrap")
    return np.pad(out, ((0, 0), (Rd, Rd), (0, 0)), constant_values=np.nan)


_CHUNK_ELEMENTS = 1 << 19  # training values copied per task (4 MiB in float64): fastest of 2^17 .. 2^20 here


def _kth_numpy(maps: np.ndarray, lay: _Layout, guard, train, wrap: bool) -> np.ndarray:
    """``X_(k)`` of every cell of ``maps (B, D, U)``, chunks of Doppler rows (and maps) in threads."""
    B, D, U = maps.shape
    Rd, Rr = guard[0] + train[0], guard[1] + train[1]
    Wd, Wr = 2 * Rd + 1, 2 * Rr + 1
    N, K = lay.n_full, lay.k_full
    padded = _padded(maps, Rd, Rr, wrap)
    out = np.empty((B, D, U), dtype=maps.dtype)
    ring = _ring(guard, train)
    maps_per = max(1, min(B, _CHUNK_ELEMENTS // (U * N)))
    rows_per = max(1, _CHUNK_ELEMENTS // (maps_per * U * N))
    tasks = [(b, d) for b in range(0, B, maps_per) for d in range(0, D, rows_per)]

    def run(task: tuple[int, int]) -> None:
        b0, d0 = task
        b1, d1 = min(B, b0 + maps_per), min(D, d0 + rows_per)
        shape = (b1 - b0, d1 - d0, U)
        view = sliding_window_view(padded[b0:b1, d0:d1 + 2 * Rd], (Wd, Wr), axis=(1, 2))
        w = np.empty(shape + (N,), dtype=maps.dtype)
        start = 0
        for rows, cols in ring:  # copy the ring as rectangles: contiguous runs, no index arrays
            h, c = rows.stop - rows.start, cols.stop - cols.start
            w[..., start:start + h * c].reshape(shape + (h, c))[...] = view[..., rows, cols]
            start += h * c
        lo, hi = np.searchsorted(lay.cut_row, (d0, d1))
        w[:, lay.cut_row[lo:hi] - d0, lay.cut_col[lo:hi], lay.cut_pos[lo:hi]] = -np.inf  # missing slots are NaN: sorted last
        w.partition(K - 1, axis=-1)
        out[b0:b1, d0:d1] = w[..., K - 1]

    workers = min(len(tasks), max(1, torch.get_num_threads()))
    if workers <= 1:
        for task in tasks:
            run(task)
    else:
        with ThreadPoolExecutor(workers) as pool:  # numpy's partition releases the GIL
            list(pool.map(run, tasks))
    return out


def _kth_of_candidates(maps: np.ndarray, lay: _Layout, alpha: np.ndarray, guard, train, wrap: bool, margin: float):
    """Cells of ``maps (B, D, U)`` with at least ``k`` training powers below ``margin * power /
    alpha`` (``alpha (D, U)``; ``b, d, u`` int64 arrays) and their ``X_(k)``: the counts in threads over chunks of
    Doppler rows, one vectorised comparison per training slot."""
    B, D, U = maps.shape
    Rd, Rr = guard[0] + train[0], guard[1] + train[1]
    padded = _padded(maps, Rd, Rr, wrap)
    offsets = _ring_offsets(guard, train) + (Rd, Rr)
    level = (maps / alpha * margin).astype(maps.dtype)
    count = np.zeros((B, D, U), dtype=np.int16 if lay.n_full < 2**15 else np.int32)
    workers = max(1, min(D, torch.get_num_threads()))
    edges = np.linspace(0, D, workers + 1).astype(int)

    def run(part: int) -> None:
        d0, d1 = edges[part], edges[part + 1]
        below = np.empty((B, d1 - d0, U), dtype=bool)
        for i, j in offsets:  # NaN (missing) is never below
            np.less(padded[:, d0 + i:d1 + i, j:j + U], level[:, d0:d1], out=below)
            count[:, d0:d1] += below

    if workers == 1:
        run(0)
    else:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(run, range(workers)))
    b, d, u = np.nonzero(count >= lay.k)
    windows = padded[b[:, None], d[:, None] + offsets[:, 0], u[:, None] + offsets[:, 1]]
    windows.sort(axis=1)  # missing cells are NaN: last
    return b, d, u, windows[np.arange(b.size), lay.k[d, u] - 1]


def _kth_torch(maps: torch.Tensor, lay: _Layout, guard, train, wrap: bool) -> torch.Tensor:
    """``X_(k)`` of every cell of ``maps (B, D, U)`` with torch ops (any device): the same
    windows, sentinels and chunks as :func:`_kth_numpy`, selected by ``torch.kthvalue``."""
    B, D, U = maps.shape
    Rd, Rr = guard[0] + train[0], guard[1] + train[1]
    Wd, Wr = 2 * Rd + 1, 2 * Rr + 1
    N, K = lay.n_full, lay.k_full
    nan = float("nan")
    padded = torch.nn.functional.pad(maps, (Rr, Rr), value=nan)
    if wrap:
        padded = torch.cat([padded[:, D - Rd:], padded, padded[:, :Rd]], dim=1)
    else:
        padded = torch.nn.functional.pad(padded, (0, 0, Rd, Rd), value=nan)
    offsets = _ring_offsets(guard, train)
    ring = torch.from_numpy((offsets[:, 0] + Rd) * Wr + offsets[:, 1] + Rr).to(maps.device)
    cut_row, cut_col, cut_pos = (torch.from_numpy(a).to(maps.device) for a in (lay.cut_row, lay.cut_col, lay.cut_pos))
    out = torch.empty_like(maps)
    rows_per = max(1, 4 * _CHUNK_ELEMENTS // (B * U * N))
    for d0 in range(0, D, rows_per):
        d1 = min(D, d0 + rows_per)
        view = padded[:, d0:d1 + 2 * Rd].unfold(1, Wd, 1).unfold(2, Wr, 1)  # (B, rows, U, Wd, Wr)
        w = view.reshape(B, d1 - d0, U, Wd * Wr)[..., ring]
        lo, hi = np.searchsorted(lay.cut_row, (d0, d1))
        w[:, cut_row[lo:hi] - d0, cut_col[lo:hi], cut_pos[lo:hi]] = -float("inf")
        out[:, d0:d1] = torch.kthvalue(w, K, dim=-1).values
    return out


def calibrate_alpha_factor(noise_maps: torch.Tensor, guard: tuple[int, int] = (2, 1), train: tuple[int, int] = (8, 4),
                           rank: float | int = 0.75, pfa: float = 1e-4, wrap_doppler: bool = False) -> dict:
    """Empirical ``alpha_factor`` for :func:`os_cfar` from noise-only maps ``noise_maps (..., D, U)``.

    Eq. 2 assumes independent training cells. Where the map's noise is correlated (an FM reference
    correlates range cells over its autocorrelation's width, a Doppler taper neighbouring rows) the
    order statistic varies more than for independent cells and the CUT is partly predicted by its
    neighbours; the net rate is no longer ``pfa`` and no closed form gives it. The factor ``f`` is the
    empirical ``1 - pfa`` quantile of ``power / (alpha X_(k))`` over all cells (edges included), so
    that the fraction of these cells over ``f alpha X_(k)`` is ``pfa``. Its error is that of a binomial
    count of ``pfa x cells`` exceedances; at least ``100 / pfa`` cells are required (the count's
    relative standard error is then at most 10 %; ``d log f`` is about ``d log(rate) / (alpha
    E X_(k))``, under 2 % for the defaults). Maps made with the same reference statistics,
    independent of those the factor is then used on. Returns ``{"alpha_factor", "cells",
    "rate_unscaled"}`` (``rate_unscaled``: the measured rate with ``f = 1``).
    """
    require(isinstance(noise_maps, torch.Tensor) and noise_maps.dim() >= 2,
            f"calibrate_alpha_factor: noise_maps must be a tensor (..., Doppler, range), got {_describe(noise_maps)}")
    cells = noise_maps.numel()
    require(cells * pfa >= 100, f"calibrate_alpha_factor: {cells} cells hold fewer than 100 expected false alarms at "
                                f"pfa {pfa:g}; give at least {math.ceil(100 / pfa)} cells")
    res = os_cfar(noise_maps, guard, train, rank, pfa, wrap_doppler=wrap_doppler, full_maps=True)
    ratio = (noise_maps.detach().double() / res.threshold.double()).reshape(-1).cpu().numpy()
    exceed = int(round(pfa * ratio.size))  # the factor puts exactly this many cells over the threshold
    f = float(np.partition(ratio, ratio.size - exceed - 1)[ratio.size - exceed - 1])
    return {"alpha_factor": f, "cells": int(ratio.size), "rate_unscaled": float((ratio > 1.0).mean())}
