"""Direct-path and clutter cancellation on the surveillance channel of one CPI.

The surveillance channel of an FM passive radar holds the direct signal and its static
multipath tens of dB above the target echoes; their range-Doppler sidelobes would bury the
echoes, so they are removed before the 2D-CCF (:mod:`.ccf`). Two cancellers, batched over the
leading dims of ``surv, ref (..., N)`` (complex samples, ``ref[n] = 0`` for ``n < 0``):

* :func:`eca`, the Extensive Cancellation Algorithm: the least-squares projection of ``surv``
  out of the subspace spanned by the reference delayed by ``0..n_range-1`` samples (optionally
  also Doppler-shifted), over the whole CPI or, as ECA-B (Colone et al. 2009), per sub-block.
  For zero Doppler only, its normal equations are formed from short FFT cross-correlations and
  a Toeplitz Gram matrix with edge corrections instead of the ``N x K`` data matrix.
* :func:`nlms`, a (block) normalised LMS adaptive canceller, the seed's choice.

:func:`cancellation_depth_db` measures either.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import torch
from scipy.fft import next_fast_len

from ..config import require
from ..errors import ConfigError
from .ccf import check_channels, ref_batch_spectra


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _fft_plan(block: int, n_lags: int) -> tuple[int, int]:
    """Segment length ``seg`` (a divisor of ``block``) and FFT length ``P >= seg + 2 n_lags - 2``
    (room for lags ``-(n_lags-1)..n_lags-1`` of an extended segment without wrap-around) that
    minimise the work per sample ``(P log2 P + 4 n_lags^2) / seg`` (the FFTs and the edge terms
    gathered at each segment boundary), over 5-smooth ``P`` up to 8192 and the whole block as
    one segment."""
    divisors = [d for d in range(1, math.isqrt(block) + 1) if block % d == 0]
    divisors = sorted(set(divisors + [block // d for d in divisors]))
    best = (block, next_fast_len(block + 2 * n_lags - 2, real=False))
    extra = 4 * n_lags**2
    best_cost = (best[1] * math.log2(best[1]) + extra) / block
    for P in sorted({2**a * 3**b * 5**c for a in range(14) for b in range(9) for c in range(6)}):
        if P > 8192:
            break
        fits = [d for d in divisors if d <= P - 2 * n_lags + 2]
        if fits:
            cost = (P * math.log2(P) + extra) / fits[-1]
            if cost < best_cost:
                best, best_cost = (fits[-1], P), cost
    return best


def _gram_fft(surv: torch.Tensor, ref: torch.Tensor, n_lags: int, batches: int):
    """Normal equations of zero-Doppler ECA(-B) without the ``N x K`` data matrix.

    Returns ``(G (..., T, K, K), rhs (..., T, K), spec, seg)``: ``spec (..., S, P)`` the FFTs of
    the reference segments extended backwards by ``K - 1`` samples (reused for the output).

    * ``rhs[i, u] = sum_{n in block i} conj(ref[n - u]) surv[n]``: per segment the circular
      cross-correlation ``IFFT(FFT(surv_seg) conj(spec))`` at lags ``u - (K-1)``; as the inverse
      FFT is linear, the products are summed over a block's segments first and one short inverse
      FFT per block replaces one per segment.
    * ``G`` from the block's lag-``k`` autocorrelation ``A[i, k] = sum_{p in block} q_k[p]``,
      ``q_k[p] = conj(ref[p]) ref[p - k]``, see :func:`_toeplitz_gram`. Per segment,
      ``IFFT(|spec|^2)`` at lag ``k`` sums ``conj(q_k[p])`` over the *extended* segment; the
      ``K - 1 - k`` terms of ``q_k`` just before the segment start are taken off again.
    """
    N, K = surv.shape[-1], n_lags
    B = N // batches
    seg, P = _fft_plan(B, K)
    per = B // seg
    spec = ref_batch_spectra(ref, seg, K, P)  # (..., S, P)
    X = torch.fft.fft(surv.reshape(*surv.shape[:-1], -1, seg), n=P, dim=-1)
    X.mul_(spec.conj())
    cross = X.reshape(*X.shape[:-2], batches, per, P).sum(-2)
    power = (spec.real**2 + spec.imag**2).reshape(*X.shape[:-2], batches, per, P).sum(-2)
    dev = ref.device
    rhs = torch.fft.ifft(cross, dim=-1).index_select(-1, torch.remainder(torch.arange(K, device=dev) - (K - 1), P))
    # sum of q_k over each block's extended segments
    autocorr = torch.fft.ifft(power.to(cross.dtype), dim=-1)[..., :K].conj_physical()

    # q_k[t - m], m = 1..K-1, k = 0..K-1, at every segment boundary t = 0, seg, ..., N, from the
    # 2K - 2 samples before each (window index j <-> ref[t - 2K + 2 + j]), and its running sums
    # C_t[u - 1, k] = sum_{m=1}^{u} q_k[t - m] (u = 1..K-1)
    m = torch.arange(1, K, device=dev)
    k = torch.arange(K, device=dev)
    padded = torch.nn.functional.pad(ref, (2 * K, 0))  # zeros before n = 0
    windows = padded[..., 2:].unfold(-1, 2 * K - 2, seg)  # (..., S+1, 2K-2), a view
    later = windows.index_select(-1, (2 * K - 2 - m[:, None] - k).reshape(-1))  # ref[t - m - k]
    # in place from here: on this scale fresh buffers cost more in page faults than the arithmetic
    C = later.view(*later.shape[:-1], K - 1, K).mul_(windows.index_select(-1, 2 * K - 2 - m).conj()[..., None])
    C = C.cumsum_(dim=-2)  # (..., S+1, K-1, K)
    # extension overcount of each segment: sum over m = 1..K-1-k, i.e. C_t[K-2-k, k]
    over = C[..., :-1, :, :].flatten(-2).index_select(-1, (K - 2 - k[:-1]) * K + k[:-1])
    acorr = autocorr
    acorr[..., :-1] -= over.reshape(*over.shape[:-2], batches, per, K - 1).sum(-2)
    # F[i, u, k] = G[i, u, u + k] = A[i, k] + S_start[u, k] - S_end[u, k] with the edge sums
    # S_t[u, k] = C_t[u - 1, k] (S_t[0, k] = 0) at the block boundaries (see _toeplitz_gram)
    edges = C[..., ::per, :, :]  # (..., T+1, K-1, K)
    F = acorr.new_empty((*acorr.shape, K))
    F[..., 0, :] = 0
    torch.sub(edges[..., :-1, :, :], edges[..., 1:, :, :], out=F[..., 1:, :])
    F += acorr[..., None, :]
    return _toeplitz_gram(F), rhs, spec, seg


def _toeplitz_gram(F: torch.Tensor) -> torch.Tensor:
    """Gram matrices ``G (..., T, K, K)`` of the delayed-reference columns of each block from
    their upper triangle by diagonals, ``F[..., u, k] = G[..., u, u + k]``.

    ``G[i, u, v] = sum_{n in block i} conj(ref[n - u]) ref[n - v]``. With ``k = v - u >= 0`` and
    ``q_k[p] = conj(ref[p]) ref[p - k]`` this is ``sum_{p = l - u}^{l + B - 1 - u} q_k[p]``
    (block start ``l``, length ``B``): the block's lag-``k`` autocorrelation
    ``A[i, k] = sum_{p in block} q_k[p]``, plus the ``u`` terms of ``q_k`` just before the block
    start, minus the ``u`` terms just before its end. The lower triangle is the Hermitian mirror.
    """
    K = F.shape[-1]
    F = F.contiguous()
    # strided reads of F: element (u, v) of `upper` is F[u, v - u] (flat index u (K-1) + v), of
    # `lower` F[v, u - v] (flat v (K-1) + u); each is valid on its own side of the diagonal
    upper = F.as_strided((*F.shape[:-2], K, K), (*F.stride()[:-2], K - 1, 1))
    lower = F.as_strided((*F.shape[:-2], K, K), (*F.stride()[:-2], 1, K - 1))
    k = torch.arange(K, device=F.device)
    G = torch.where(k[None, :] >= k[:, None], upper, lower)
    # conjugate below the diagonal (Hermitian), zero imaginary part on it (real in exact arithmetic)
    G.imag.mul_(torch.sign(k[None, :] - k[:, None]).to(G.real.dtype))
    return G


def _fir_per_block(spec: torch.Tensor, w: torch.Tensor, n_lags: int, seg: int, shape) -> torch.Tensor:
    """``y[n] = sum_u w[i, u] ref[n - u]`` ``(shape)`` with block ``i``'s weights ``w (..., T, K)``,
    from the extended reference segment spectra ``spec (..., S, P)`` of :func:`_gram_fft` (which
    it overwrites): per segment a circular convolution with the weights, linear (no wrap-around)
    at outputs ``K-1 .. K-2+seg`` as ``P >= seg + K - 1``."""
    n_fft = spec.shape[-1]
    y = spec.reshape(*spec.shape[:-2], w.shape[-2], -1, n_fft)
    y.mul_(torch.fft.fft(w, n=n_fft, dim=-1)[..., None, :])
    torch.fft.ifft(y, dim=-1, out=y)
    return y[..., n_lags - 1: n_lags - 1 + seg].reshape(shape)


def eca(surv, ref, n_range: int, doppler_bins=(0,), batches: int = 1, *,
        method: Literal["auto", "fft", "matmul"] = "auto",
        diagonal_loading: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Extensive Cancellation Algorithm (ECA; ECA-B for ``batches > 1``).

    ``surv, ref (..., N)`` complex samples. The CPI is split into ``batches`` equal blocks of
    ``B = N / batches`` samples (``batches = 1``: plain ECA); in block ``i`` starting at ``l``
    the columns are ``x_{d,u}[n] = ref[n - u] exp(j 2 pi d (n - l) / B)`` for ``u`` in
    ``0..n_range-1`` and ``d`` in ``doppler_bins`` (integer Doppler bins of the block length,
    ``d fs / B`` Hz; ``ref`` of the previous block where ``n - u`` crosses ``l``, zero before
    ``n = 0``), the weights ``w = (X^H X)^{-1} X^H surv`` are solved per block, and the block's
    cleaned samples are ``surv - X w``.

    The normal equations are solved in complex128 by Cholesky, without regularisation unless
    ``diagonal_loading > 0`` (added to the diagonal as a fraction of its mean); a Gram matrix that
    is not numerically positive definite (e.g. a zero or periodic reference) raises
    :class:`~pmsr_nn.errors.ConfigError`. ``method="fft"`` (the default for zero Doppler only)
    forms ``X^H X`` and ``X^H surv`` from FFT cross-correlations and ``X w`` by FFT convolution;
    ``"matmul"`` builds the ``B x K`` matrix of each block (any Doppler bins).

    Returns ``(cleaned (..., N), weights (..., batches, K))`` with ``K = len(doppler_bins) *
    n_range`` and column ``j = i_d * n_range + u`` (Doppler-major, in the order given), cleaned in
    the inputs' complex dtype, weights complex128.
    """
    surv, ref = check_channels(surv, ref, n_range)
    out_dtype = surv.dtype
    surv, ref = surv.to(torch.complex128), ref.to(torch.complex128)
    N = surv.shape[-1]
    dop = list(doppler_bins) if not isinstance(doppler_bins, torch.Tensor) else doppler_bins.tolist()
    require(len(dop) >= 1 and all(_is_int(d) for d in dop), f"doppler_bins must be integers, got {doppler_bins!r}")
    require(len(set(dop)) == len(dop), f"doppler_bins must be distinct, got {dop}")
    require(_is_int(batches) and batches >= 1, f"batches must be a positive integer, got {batches!r}")
    require(N % batches == 0, f"{batches} batches do not divide the CPI of {N} samples")
    B = N // batches
    K = len(dop) * n_range
    require(B > K, f"an ECA block of {B} samples must exceed its {K} unknowns (n_range x Doppler bins)")
    require(method in ("auto", "fft", "matmul"), f"unknown ECA method {method!r}; choose auto, fft or matmul")
    require(method != "fft" or dop == [0], "the fft ECA method handles zero Doppler only; use method='matmul'")
    require(math.isfinite(diagonal_loading) and diagonal_loading >= 0,
            f"diagonal_loading must be >= 0, got {diagonal_loading}")
    fast = method == "fft" or (method == "auto" and dop == [0])

    if fast:
        G, rhs, spec, seg = _gram_fft(surv, ref, n_range, batches)
    else:
        X = _eca_columns(ref, n_range, dop, batches)  # (..., T, B, K)
        s = surv.reshape(*surv.shape[:-1], batches, B, 1)
        G = X.mH @ X
        rhs = (X.mH @ s)[..., 0]

    if diagonal_loading > 0:
        load = diagonal_loading * G.diagonal(dim1=-2, dim2=-1).real.mean(-1)
        G = G + load[..., None, None] * torch.eye(K, dtype=G.dtype, device=G.device)
    L, info = torch.linalg.cholesky_ex(G)
    if bool((info != 0).any()):
        raise ConfigError("the ECA Gram matrix is not positive definite (reference rank deficient: zero or "
                          "periodic?); set diagonal_loading > 0")
    w = torch.cholesky_solve(rhs[..., None], L)[..., 0]  # (..., T, K)

    if fast:
        y = _fir_per_block(spec, w, n_range, seg, surv.shape)
    else:
        y = (X @ w[..., None]).reshape(surv.shape)
    return (surv - y).to(out_dtype), w


def _eca_columns(ref: torch.Tensor, n_range: int, dop: list[int], batches: int) -> torch.Tensor:
    """ECA data matrices ``X (..., T, B, D * n_range)`` (see :func:`eca` for the columns)."""
    N = ref.shape[-1]
    B = N // batches
    padded = torch.nn.functional.pad(ref, (n_range - 1, 0))
    delayed = torch.stack([padded[..., n_range - 1 - u: n_range - 1 - u + N] for u in range(n_range)], dim=-1)
    delayed = delayed.reshape(*ref.shape[:-1], batches, B, n_range)
    n = torch.arange(B, dtype=torch.float64, device=ref.device)
    d = torch.tensor(dop, dtype=torch.float64, device=ref.device)
    phasor = torch.polar(torch.ones(B, len(dop), dtype=torch.float64, device=ref.device),
                         2 * math.pi * n[:, None] * d / B)
    X = delayed[..., None, :] * phasor[:, :, None]  # (..., T, B, D, n_range)
    return X.reshape(*X.shape[:-2], len(dop) * n_range)


def nlms(surv, ref, n_taps: int, mu: float, block: int = 64, *, eps: float = 1e-12,
         weights=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Block normalised LMS canceller of the direct path and static clutter.

    ``surv, ref (..., N)`` complex samples; regressor ``x_n = (ref[n], ref[n-1], ...,
    ref[n-n_taps+1])`` (zero before ``n = 0``), estimate ``y[n] = x_n^T w`` and error (the cleaned
    output) ``e[n] = surv[n] - y[n]``. The samples are taken in blocks of ``block`` (the last may
    be shorter); within block ``j`` all errors use the weights ``w_j`` it started with, then

        w_{j+1} = w_j + mu * sum_{n in block j} conj(x_n) e[n] / (eps + sum_{n in block j} |x_n|^2).

    ``block = 1`` is the classic sample-by-sample NLMS; ``0 < mu < 2`` is the stable range (the
    normalised step matrix has eigenvalues in ``[0, 1]``). ``eps`` (power units of the samples)
    guards an all-zero block; ``weights (..., n_taps)`` are the initial weights (default zero).
    The weights move about once per block, so convergence takes ``block`` times more samples
    than the sample-by-sample NLMS (for a coloured reference such as FM, small blocks matter).

    Computation: with ``G_j = X_j^H X_j``, ``r_j = X_j^H surv_j`` (``X_j`` the block's regressor
    rows) and ``mu_j = mu / (eps + tr G_j)`` the update is the affine recursion
    ``w_{j+1} = (I - mu_j G_j) w_j + mu_j r_j``. For ``block >= max(n_taps, 2)`` all ``G_j, r_j``
    come at once from the FFT normal equations of ECA-B (one ECA block per NLMS block), the
    recursion runs on ``K x K`` matrices only, and the outputs are one FFT filtering with
    per-block weights; smaller blocks (and a short last block) loop over the blocks on the
    samples. Batched over the leading dims.

    Computed in complex128; returns ``(cleaned (..., N) in the inputs' complex dtype, final
    weights (..., n_taps) complex128)``.
    """
    require(_is_int(n_taps) and n_taps >= 1, f"n_taps must be a positive integer, got {n_taps!r}")
    surv, ref = check_channels(surv, ref, n_taps)
    out_dtype = surv.dtype
    surv, ref = surv.to(torch.complex128), ref.to(torch.complex128)
    require(isinstance(mu, (int, float, np.floating)) and 0 < mu < 2, f"NLMS mu must lie in (0, 2), got {mu}")
    require(_is_int(block) and block >= 1, f"NLMS block must be a positive integer, got {block!r}")
    require(math.isfinite(eps) and eps >= 0, f"NLMS eps must be >= 0, got {eps}")
    N, K = surv.shape[-1], n_taps
    lead = surv.shape[:-1]
    if weights is None:
        w = surv.new_zeros((*lead, K))
    else:
        w = torch.as_tensor(weights).to(device=surv.device, dtype=surv.dtype)
        require(w.shape == (*lead, K), f"initial NLMS weights must have shape {(*lead, K)}, got {tuple(w.shape)}")
        require(bool(torch.isfinite(w).all()), "initial NLMS weights contain NaN or inf")
    # X[..., n, j] = ref[n - (K - 1 - j)]: a strided view of the zero-padded reference (no N x K
    # copy), its taps in reverse order
    X = torch.nn.functional.pad(ref, (K - 1, 0)).unfold(-1, K, 1)
    out = torch.empty_like(surv)
    done = 0
    n_full = N // block
    # the affine path gathers K^2 edge terms per block: from block >= K on, no more than X holds
    if block >= max(K, 2) and n_full >= 1:
        done = n_full * block
        G, rhs, spec, seg = _gram_fft(surv[..., :done], ref[..., :done], K, n_full)
        step = mu / (eps + G.diagonal(dim1=-2, dim2=-1).real.sum(-1))  # (..., nb)
        A = G.mul_(-step[..., None, None])  # I - step G, in place (20 MB at 5000 blocks of K = 16)
        A.diagonal(dim1=-2, dim2=-1).add_(1)
        b = step[..., None] * rhs
        # the recursion on K x K numbers: numpy's per-call overhead is a fraction of torch's
        An = A.reshape(-1, n_full, K, K).cpu().numpy()
        bn = b.reshape(-1, n_full, K, 1).cpu().numpy()
        wn = w.reshape(-1, K, 1).cpu().numpy()
        W = np.empty((wn.shape[0], n_full, K), dtype=np.complex128)
        for j in range(n_full):
            W[:, j] = wn[..., 0]
            wn = An[:, j] @ wn + bn[:, j]
        W = torch.from_numpy(W).to(device=surv.device).reshape(*lead, n_full, K)
        out[..., :done] = surv[..., :done] - _fir_per_block(spec, W, K, seg, (*lead, done))
        w = torch.from_numpy(wn[..., 0]).to(surv.device).reshape(*lead, K)
    # sample-domain blocks (all of them for small blocks, else the short last one)
    w = w.flip(-1)[..., None]  # taps reversed to match X
    for start in range(done, N, block):
        stop = min(start + block, N)
        xb = X[..., start:stop, :]
        e = surv[..., start:stop] - (xb @ w)[..., 0]
        out[..., start:stop] = e
        energy = (xb.real**2 + xb.imag**2).sum((-1, -2))
        w = w + (mu / (eps + energy))[..., None, None] * (xb.mH @ e[..., None])
    return out.to(out_dtype), w[..., 0].flip(-1)


def cancellation_depth_db(before, after) -> torch.Tensor:
    """Cancellation depth (dB) ``(...,)``: ``10 log10(sum |before|^2 / sum |after|^2)`` over the
    last (sample) axis of ``before, after (..., N)``."""
    before, after = torch.as_tensor(before), torch.as_tensor(after)
    require(before.shape == after.shape, f"before {tuple(before.shape)} and after {tuple(after.shape)} shapes differ")
    p0 = before.abs().square().sum(-1)
    p1 = after.abs().square().sum(-1)
    return 10 * torch.log10(p0 / p1)
