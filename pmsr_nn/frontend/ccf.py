"""Range-Doppler map of one CPI: the 2D cross-correlation function (2D-CCF, Eq. 1 of the seed).

For a reference channel ``ref (..., N)`` and a surveillance channel ``surv (..., N)`` of complex
baseband samples at ``fs``, the seed's Eq. 1 is

    chi(u, m) = sum_{n=0}^{N-1} surv[n] conj(ref[n - u]) exp(-j 2 pi m n / N),

``u`` the delay bin (``tau = u / fs``), ``m`` the Doppler bin (``f_d = m fs / N``) and
``ref[n] = 0`` for ``n < 0`` (a zero-fill shift, the convention of the whole front end). Maps are
shaped ``(..., n_doppler, n_range)``: Doppler rows, range columns.

Two evaluations:

* :func:`ccf_direct` is Eq. 1 itself, for any chosen Doppler bins: per lag one FFT of length
  ``N``. Exact but ``n_range`` full-length FFTs; the reference for tests and small cases.
* :func:`ccf_batches` is the standard *batches* algorithm of passive radar: the CPI is cut into
  ``Nb`` batches of ``L`` samples, each batch's cross-correlation over the wanted lags is formed
  with short FFTs, and a Doppler FFT runs over the batch index. It costs a few FFTs of about
  ``N (1 + n_range / L)`` points in all. The approximation: the Doppler phase
  ``exp(-j 2 pi f n / fs)`` is held at its value at the start of each batch, so an echo of
  Doppler ``f`` adds up within a batch with the gain
  ``|sin(pi f L / fs) / (L sin(pi f / fs))|`` (the *straddle* loss of the batches algorithm):
  none at zero Doppler, ``2 / pi`` (-3.9 dB) at the edge ``fs / (2 L)`` of its unambiguous
  Doppler span (e.g. 200 Hz for ``L = 800`` at 320 kHz).

Both work in the inputs' complex dtype (complex128 unless given complex64) and are batched over
the leading dims without a Python loop over them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.fft import next_fast_len
from scipy.signal import get_window

from ..config import require

WINDOWS = ("none", "hann", "hamming", "blackman", "blackmanharris")
"""Doppler tapers :func:`ccf_batches` knows (periodic, i.e. DFT-even, versions)."""


@dataclass
class RangeDopplerMap:
    """A range-Doppler map from :func:`ccf_batches`.

    ``values (..., D, U)`` complex: ``D`` Doppler rows in increasing frequency, ``U`` range
    columns (lags ``0..U-1`` samples); ``doppler_bins (D,)`` int64 the signed bin index ``k`` of
    each row and ``doppler_hz (D,)`` float64 its frequency ``k * bin_hz``; ``fs`` the sample rate
    (Hz) and ``bin_hz`` the Doppler bin spacing ``fs / (batch_len * doppler_fft)`` (Hz).
    """

    values: torch.Tensor
    doppler_bins: torch.Tensor
    doppler_hz: torch.Tensor
    fs: float
    bin_hz: float

    @property
    def delay_s(self) -> torch.Tensor:
        """Delay (s) of each range column ``(U,)``: ``u / fs``."""
        return torch.arange(self.values.shape[-1], dtype=torch.float64) / self.fs

    @property
    def power(self) -> torch.Tensor:
        """``|values|^2`` ``(..., D, U)`` real."""
        return self.values.real**2 + self.values.imag**2


def doppler_bin_range(max_doppler_hz: float, bin_hz: float) -> torch.Tensor:
    """Signed Doppler bins ``-K..K`` ``(2K+1,)`` int64 with ``|k| bin_hz <= max_doppler_hz``.

    A relative slack of ``1e-9`` keeps a limit that is a whole number of bins (200 Hz at 1 Hz)
    from losing its edge bins to rounding.
    """
    require(math.isfinite(max_doppler_hz) and max_doppler_hz >= 0,
            f"max_doppler_hz must be finite and >= 0, got {max_doppler_hz}")
    require(math.isfinite(bin_hz) and bin_hz > 0, f"the Doppler bin spacing must be positive, got {bin_hz}")
    K = int(math.floor(max_doppler_hz / bin_hz * (1 + 1e-9)))
    return torch.arange(-K, K + 1, dtype=torch.int64)


def doppler_frequencies(bins, fs: float, length: int) -> torch.Tensor:
    """Doppler frequency (Hz) ``(D,)`` float64 of signed bins of a DFT over ``length`` samples at
    ``fs``: ``bins * fs / length``. For :func:`ccf_direct` ``length = N``; for the batches
    algorithm ``length = batch_len * doppler_fft``."""
    return torch.as_tensor(bins, dtype=torch.float64) * (fs / length)


def as_complex(x, name: str) -> torch.Tensor:
    """``x`` as a complex tensor (real input promoted to complex128; complex64 kept), checked
    to hold at least one sample on its last axis and no NaN or inf."""
    t = torch.as_tensor(x)
    if not t.is_complex():
        t = t.to(torch.complex128)
    require(t.dim() >= 1 and t.shape[-1] > 0, f"{name} samples must be a non-empty (..., N) array")
    # one sum is ~10x cheaper than isfinite over N samples and is non-finite whenever a sample
    # is; the full check then tells a NaN/inf from a mere overflow of the sum
    if not bool(torch.isfinite(torch.view_as_real(t).sum())):
        require(bool(torch.isfinite(t).all()), f"{name} samples contain NaN or inf")
    return t


def check_channels(surv, ref, n_range: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Validated ``(surv, ref)`` of the same shape ``(..., N)`` and complex dtype, ``1 <= n_range < N``."""
    surv, ref = as_complex(surv, "surveillance"), as_complex(ref, "reference")
    require(surv.shape == ref.shape,
            f"surveillance {tuple(surv.shape)} and reference {tuple(ref.shape)} shapes differ")
    require(isinstance(n_range, (int, np.integer)) and not isinstance(n_range, bool) and n_range >= 1,
            f"n_range must be a positive integer, got {n_range!r}")
    N = surv.shape[-1]
    require(N > n_range, f"a CPI of {N} samples is not longer than the longest delay ({n_range} lags)")
    dtype = torch.promote_types(surv.dtype, ref.dtype)
    return surv.to(dtype), ref.to(dtype)


def ccf_direct(surv, ref, n_range: int, doppler_bins, window=None) -> torch.Tensor:
    """Eq. 1 exactly: ``chi (..., D, n_range)`` for lags ``0..n_range-1`` and the given bins.

    ``surv, ref (..., N)`` complex samples; ``doppler_bins`` a 1-D int sequence/tensor of signed
    bins ``m`` (frequency ``m fs / N``; ``m`` and ``m + N`` are the same bin), rows in the order
    given; ``window`` an optional real or complex taper ``(N,)`` multiplying the product over
    ``n``. Per lag the product ``surv[n] conj(ref[n - u])`` and one FFT of length ``N``
    (``O(n_range N log N)``).
    """
    surv, ref = check_channels(surv, ref, n_range)
    N = surv.shape[-1]
    bins = torch.as_tensor(doppler_bins)
    require(bins.dim() == 1 and bins.numel() >= 1 and not bins.is_floating_point() and not bins.is_complex()
            and bins.dtype != torch.bool, "doppler_bins must be a non-empty 1-D sequence of integers")
    idx = torch.remainder(bins.to(torch.int64), N).to(surv.device)
    if window is not None:
        window = torch.as_tensor(window)
        require(window.shape == (N,), f"the window must have shape ({N},), got {tuple(window.shape)}")
        require(bool(torch.isfinite(window).all()), "the window contains NaN or inf")
        window = window.to(device=surv.device, dtype=surv.dtype)
    out = surv.new_empty((*surv.shape[:-1], idx.numel(), n_range))
    for u in range(n_range):
        prod = surv[..., u:] * ref[..., : N - u].conj()  # n >= u; ref[n - u] = 0 before
        if window is not None:
            prod = prod * window[u:]
        # pad at the front back to n = 0..N-1 so the FFT phase is exp(-j 2 pi m n / N)
        prod = torch.nn.functional.pad(prod, (u, 0)) if u else prod
        out[..., u] = torch.fft.fft(prod, dim=-1).index_select(-1, idx)
    return out


def _fft_len(batch_len: int, n_lags: int) -> int:
    """Fast FFT length for a batch's linear correlation over ``n_lags`` lags (no wrap-around)."""
    return next_fast_len(batch_len + n_lags - 1, real=False)


def ref_batch_spectra(ref: torch.Tensor, batch_len: int, n_lags: int, n_fft: int) -> torch.Tensor:
    """FFTs ``(..., Nb, n_fft)`` of each batch's reference samples extended backwards by
    ``n_lags - 1``: row ``b`` holds ``ref[b L - (n_lags-1) .. b L + L - 1]`` (zero before n = 0)."""
    padded = torch.nn.functional.pad(ref, (n_lags - 1, 0))
    segs = padded.unfold(-1, batch_len + n_lags - 1, batch_len)  # a view: overlapping windows
    return torch.fft.fft(segs, n=n_fft, dim=-1)


def batch_xcorr(x: torch.Tensor, ref_spec: torch.Tensor, batch_len: int, n_lags: int) -> torch.Tensor:
    """Per-batch cross-correlation ``c (..., Nb, n_lags)``:
    ``c[b, u] = sum_{n in batch b} x[n] conj(ref[n - u])`` (zero-fill shift), from the reference
    spectra of :func:`ref_batch_spectra`.

    With ``r_b`` the extended reference batch, ``c[b, u] = z[u - (n_lags-1)]`` where
    ``z[k] = sum_j x_b[j + k] conj(r_b[j])`` is the circular cross-correlation, free of
    wrap-around for ``n_fft >= batch_len + n_lags - 1``.
    """
    n_fft = ref_spec.shape[-1]
    xs = x.reshape(*x.shape[:-1], -1, batch_len)
    z = torch.fft.fft(xs, n=n_fft, dim=-1)
    # in place: each fresh multi-MB buffer costs page faults comparable to the FFT itself
    z.mul_(ref_spec.conj())
    torch.fft.ifft(z, dim=-1, out=z)
    idx = torch.remainder(torch.arange(n_lags, device=z.device) - (n_lags - 1), n_fft)
    return z.index_select(-1, idx)


def doppler_window(name: str, n: int) -> np.ndarray:
    """Periodic (DFT-even, ``scipy.signal.get_window(..., fftbins=True)``) taper of ``n`` points;
    ``"none"`` is all ones."""
    require(name in WINDOWS, f"unknown Doppler window {name!r}; choose one of {', '.join(WINDOWS)}")
    if name == "none":
        return np.ones(n)
    return get_window(name, n, fftbins=True)


def ccf_batches(surv, ref, n_range: int, batch_len: int, max_doppler_hz: float, fs: float,
                window: str = "none", doppler_fft: int | None = None) -> RangeDopplerMap:
    """Range-Doppler map by the *batches* algorithm (see the module docstring).

    ``surv, ref (..., N)`` complex samples at ``fs`` (Hz); the CPI is split into
    ``Nb = N // batch_len`` batches (``batch_len`` must divide ``N`` and be ``>= n_range``).
    Per batch ``b`` the exact cross-correlation
    ``c_b(u) = sum_{n in batch b} surv[n] conj(ref[n - u])``, ``u = 0..n_range-1`` (reference
    samples of the previous batch where ``n - u`` crosses the batch start, zero before ``n = 0``)
    comes from FFTs of a fast length ``>= batch_len + n_range - 1``; then, with ``w_b`` the
    periodic taper ``window`` over the ``Nb`` batches (``none``, ``hann``, ``hamming``,
    ``blackman``, ``blackmanharris``) and ``M = doppler_fft`` (default ``Nb``; larger zero-pads),

        chi(u, k) = sum_b w_b c_b(u) exp(-j 2 pi k b / M),   f_k = k fs / (batch_len M),

    i.e. Eq. 1 with its phase taken at each batch's start ``n = b batch_len``. Rows with
    ``|f_k| <= max_doppler_hz`` are kept, in increasing frequency; ``max_doppler_hz`` may not
    exceed ``fs / (2 batch_len)``, the unambiguous span (at exactly that value the first and last
    rows are the same, aliased, bin).

    Returns a :class:`RangeDopplerMap` with ``values (..., D, n_range)`` in the inputs' dtype.
    """
    surv, ref = check_channels(surv, ref, n_range)
    N = surv.shape[-1]
    require(math.isfinite(fs) and fs > 0, f"the sample rate must be positive, got {fs}")
    require(isinstance(batch_len, (int, np.integer)) and batch_len >= n_range,
            f"batch_len must be an integer >= n_range ({n_range}), got {batch_len!r}")
    require(N % batch_len == 0, f"batch_len {batch_len} does not divide the CPI of {N} samples")
    n_batches = N // batch_len
    M = n_batches if doppler_fft is None else doppler_fft
    require(isinstance(M, (int, np.integer)) and M >= n_batches,
            f"doppler_fft must be an integer >= the {n_batches} batches, got {doppler_fft!r}")
    bin_hz = fs / (batch_len * M)
    bins = doppler_bin_range(max_doppler_hz, bin_hz)
    require(max_doppler_hz <= fs / (2 * batch_len) * (1 + 1e-9),
            f"max_doppler_hz {max_doppler_hz:g} exceeds the unambiguous span fs / (2 batch_len) = "
            f"{fs / (2 * batch_len):g} Hz of {batch_len}-sample batches")
    taper = doppler_window(window, n_batches)  # checks the name before any work

    spec = ref_batch_spectra(ref, batch_len, n_range, _fft_len(batch_len, n_range))
    c = batch_xcorr(surv, spec, batch_len, n_range)  # (..., Nb, U)
    if window != "none":
        c = c * torch.as_tensor(taper, dtype=c.real.dtype, device=c.device)[:, None]
    chi = torch.fft.fft(c, n=M, dim=-2)
    values = chi.index_select(-2, torch.remainder(bins, M).to(chi.device))
    return RangeDopplerMap(values, bins, bins.to(torch.float64) * bin_hz, float(fs), bin_hz)
