"""Range-Doppler maps (2D-CCF) and clutter cancellation of the passive radar front end.

Every expected value is computed independently here: Eq. 1 and the batches algorithm's own
defining sum by explicit numpy sums, ECA by ``numpy.linalg.lstsq``, NLMS by a per-sample loop,
and pyAPRiL 1.7.6 (a test-only dependency) as an outside oracle where its algorithms coincide
with ours. Float64 sums of a few thousand terms agree to ~1e-14 relative, so ``1e-9`` leaves
ample room for rounding while any indexing, sign or phase slip is O(1).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from scipy.signal import get_window

from pmsr_nn.errors import ConfigError
from pmsr_nn.frontend.cancellation import cancellation_depth_db, eca, nlms
from pmsr_nn.frontend.ccf import (ccf_batches, ccf_direct, doppler_bin_range,
                                  doppler_frequencies)


def cnoise(rng: np.random.Generator, *shape: int) -> np.ndarray:
    """Unit-power circular complex white Gaussian samples."""
    return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / math.sqrt(2)


def delayed(x: np.ndarray, u: int) -> np.ndarray:
    """``x[n - u]`` along the last axis, zero before ``n = 0``."""
    out = np.zeros_like(x)
    out[..., u:] = x[..., : x.shape[-1] - u]
    return out


def rel_err(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / np.abs(b).max())


# ---------------------------------------------------------------------------------------------
# 2D-CCF
# ---------------------------------------------------------------------------------------------


def test_single_echo_peaks_at_its_delay_and_doppler():
    """A noise-free echo ``a ref[n - u0] exp(j 2 pi m0 n / N)``: ``chi(u0, m0)`` of Eq. 1 is
    ``a sum |ref|^2`` exactly; with 1 Hz bins in both algorithms the batches map peaks at
    ``(u0, m0 Hz)`` with the value of its own sum (Doppler phase held at the batch starts)."""
    rng = np.random.default_rng(1)
    N, L, fs, u0, m0, U = 8192, 64, 8192.0, 11, 17, 32  # fs / N = 1 Hz = fs / (L Nb)
    a = np.array([2.0 - 1.0j, 0.5j])
    ref = cnoise(rng, 2, N)
    n = np.arange(N)
    surv = a[:, None] * delayed(ref, u0) * np.exp(2j * np.pi * m0 * n / N)

    bins = doppler_bin_range(50.0, fs / N)
    chi = ccf_direct(torch.tensor(surv), torch.tensor(ref), U, bins).numpy()
    assert chi.shape == (2, bins.numel(), U)
    for i in range(2):
        row, col = np.unravel_index(np.abs(chi[i]).argmax(), chi[i].shape)
        assert (int(bins[row]), col) == (m0, u0)
        expected = a[i] * np.sum(np.abs(ref[i, : N - u0]) ** 2)
        assert abs(chi[i, row, col] - expected) <= 1e-12 * abs(expected)

    rd = ccf_batches(torch.tensor(surv), torch.tensor(ref), U, L, 50.0, fs)
    assert rd.values.shape == (2, 101, U)
    assert rd.bin_hz == pytest.approx(1.0) and torch.equal(rd.doppler_hz, torch.arange(-50.0, 51.0))
    assert torch.allclose(rd.delay_s, torch.arange(U) / fs)
    v = rd.values.numpy()
    for i in range(2):
        row, col = np.unravel_index(np.abs(v[i]).argmax(), v[i].shape)
        assert (float(rd.doppler_hz[row]), col) == (m0, u0)
        # the within-batch phase exp(j 2 pi m0 (n mod L) / N) is what the batches algorithm keeps
        expected = a[i] * np.sum(np.abs(delayed(ref[i], u0)) ** 2 * np.exp(2j * np.pi * m0 * (n % L) / N))
        assert abs(v[i, row, col] - expected) <= 1e-12 * abs(expected)


def test_ccf_direct_equals_eq1_evaluated_term_by_term():
    """Eq. 1 with a taper, leading dims (2, 3), negative bins and a bin given as ``m + N``."""
    rng = np.random.default_rng(2)
    N, U = 256, 9
    surv, ref = cnoise(rng, 2, 3, N), cnoise(rng, 2, 3, N)
    window = rng.uniform(0.2, 1.0, N)
    bins = np.array([-7, 0, 3, 100, 3 + N, -N + 5])
    n = np.arange(N)
    shifted = np.stack([delayed(ref, u) for u in range(U)], axis=-2)  # (2, 3, U, N)
    phase = np.exp(-2j * np.pi * np.outer(bins, n) / N)  # (D, N)
    expected = np.einsum("...n,...un,dn,n->...du", surv, shifted.conj(), phase, window)
    got = ccf_direct(torch.tensor(surv), torch.tensor(ref), U, torch.tensor(bins), window=torch.tensor(window))
    assert got.shape == (2, 3, len(bins), U)
    assert rel_err(got.numpy(), expected) < 1e-9
    assert np.allclose(got[..., 2, :].numpy(), got[..., 4, :].numpy(), rtol=0, atol=1e-9)  # m = m + N
    assert doppler_frequencies(bins, 1000.0, N)[1:3].tolist() == [0.0, 3 * 1000.0 / N]


@pytest.mark.parametrize("window", ["none", "hann", "hamming", "blackman", "blackmanharris"])
def test_ccf_batches_equals_its_defining_sum(window):
    """``chi(u, k) = sum_b w_b exp(-j 2 pi k b / M) sum_{n in batch b} surv[n] conj(ref[n - u])``
    with a periodic taper, a zero-padded Doppler FFT (``M = 16 > Nb = 10``) and leading dims."""
    rng = np.random.default_rng(3)
    L, Nb, M, U, fs = 24, 10, 16, 7, 1000.0
    N = L * Nb
    surv, ref = cnoise(rng, 3, N), cnoise(rng, 3, N)
    bin_hz = fs / (L * M)
    rd = ccf_batches(torch.tensor(surv), torch.tensor(ref), U, L, 20.0, fs, window=window, doppler_fft=M)
    K = int(20.0 // bin_hz)
    k = np.arange(-K, K + 1)
    assert rd.doppler_bins.tolist() == k.tolist()
    assert np.allclose(rd.doppler_hz.numpy(), k * bin_hz, rtol=1e-15)

    w = np.ones(Nb) if window == "none" else get_window(window, Nb, fftbins=True)
    products = np.stack([surv * delayed(ref, u).conj() for u in range(U)], axis=-1)  # (3, N, U)
    c = products.reshape(3, Nb, L, U).sum(-2)  # (3, Nb, U)
    phase = np.exp(-2j * np.pi * np.outer(k, np.arange(Nb)) / M)  # (D, Nb)
    expected = np.einsum("db,b,...bu->...du", phase, w, c)
    assert rel_err(rd.values.numpy(), expected) < 1e-9


def _pyapril_case(seed: int):
    pytest.importorskip("pyapril")
    from pyapril.detector import cc_detector_ons

    rng = np.random.default_rng(seed)
    L, Nb, fs = 64, 20, 1000.0
    N = L * Nb
    fmax = 10.5 * fs / (2 * N)  # pyapril keeps int(fmax / step) = 10 bins each side; so do we
    return cc_detector_ons, rng, L, Nb, N, fs, fmax


def test_ccf_batches_matches_pyapril_cc_detector_ons():
    """pyAPRiL's ``cc_detector_ons(ref, surv, fs, fD_max, r_max)`` is the batches algorithm with
    batch length ``r_max``, lags ``0..r_max-1`` and a Doppler FFT zero-padded to ``2 Nb``: its
    rows are bins ``-D..D`` of ``fs / (2 N)`` (``D = int(fD_max / step)``) in increasing
    frequency with our sign, i.e. ``ccf_batches(surv, ref, r_max, r_max, fD_max, fs,
    doppler_fft=2 Nb)``. One difference: it groups the products ``surv[n] conj(ref[n - u])`` by
    the *reference* sample's batch (``n - u`` in batch b), we by the surveillance sample's (``n``
    in batch b). So (1) the zero-Doppler row agrees for any signals; (2) all rows agree for lags
    ``< U`` when ``ref`` is zero on the last ``U - 1`` samples of each batch (no product then
    straddles a batch start); (3) in general, reversing time maps one onto the other: with
    ``s'[n] = conj(ref[N-1-n])`` and ``r'[n] = conj(surv[N-1-n])`` the batches run backwards, so
    ``pyapril[k] = exp(-j 2 pi k (Nb - 1) / (2 Nb)) ours(s', r')[-k]``."""
    cc_detector_ons, rng, L, Nb, N, fs, fmax = _pyapril_case(4)
    ref, surv = cnoise(rng, N), cnoise(rng, N)
    theirs = cc_detector_ons(ref, surv, fs, fmax, L)
    ours = ccf_batches(torch.tensor(surv), torch.tensor(ref), L, L, fmax, fs, doppler_fft=2 * Nb)
    D = 10
    assert theirs.shape == tuple(ours.values.shape) == (2 * D + 1, L)
    assert ours.doppler_hz.numpy() == pytest.approx(np.arange(-D, D + 1) * fs / (2 * N))
    assert rel_err(ours.values[D].numpy(), theirs[D]) < 1e-9  # (1)
    assert rel_err(ours.values[D + 1].numpy(), theirs[D + 1]) > 1e-2  # the grouping does differ

    reversed_ = ccf_batches(torch.tensor(np.conj(ref[::-1]).copy()), torch.tensor(np.conj(surv[::-1]).copy()),
                            L, L, fmax, fs, doppler_fft=2 * Nb).values.numpy()
    k = np.arange(-D, D + 1)
    mapped = np.exp(-2j * np.pi * k * (Nb - 1) / (2 * Nb))[:, None] * reversed_[::-1]
    assert rel_err(mapped, theirs) < 1e-9  # (3)


def test_ccf_batches_matches_pyapril_with_batch_gated_reference():
    cc_detector_ons, rng, L, Nb, N, fs, fmax = _pyapril_case(5)
    U = 16
    ref, surv = cnoise(rng, Nb, L), cnoise(rng, N)
    ref[:, L - (U - 1):] = 0  # (2) of the test above
    ref = ref.ravel()
    theirs = cc_detector_ons(ref, surv, fs, fmax, L)
    ours = ccf_batches(torch.tensor(surv), torch.tensor(ref), U, L, fmax, fs, doppler_fft=2 * Nb)
    assert rel_err(ours.values.numpy(), theirs[:, :U]) < 1e-9


def test_ccf_complex64_is_kept_and_close():
    rng = np.random.default_rng(6)
    surv, ref = cnoise(rng, 4096), cnoise(rng, 4096)
    hi = ccf_batches(torch.tensor(surv), torch.tensor(ref), 16, 64, 30.0, 4096.0).values
    lo = ccf_batches(torch.tensor(surv).to(torch.complex64), torch.tensor(ref).to(torch.complex64),
                     16, 64, 30.0, 4096.0).values
    assert lo.dtype == torch.complex64
    assert rel_err(lo.to(torch.complex128).numpy(), hi.numpy()) < 1e-5  # single precision


# ---------------------------------------------------------------------------------------------
# ECA
# ---------------------------------------------------------------------------------------------


def _clutter(rng, ref: np.ndarray, delays=(0, 2, 5, 11), scale=1e3) -> np.ndarray:
    amps = cnoise(rng, *ref.shape[:-1], len(delays)) * scale
    return sum(amps[..., i, None] * delayed(ref, d) for i, d in enumerate(delays))


@pytest.mark.parametrize("method", ["fft", "matmul"])
@pytest.mark.parametrize("batches", [1, 4])
@pytest.mark.parametrize("kind", ["white", "fm"])
def test_eca_removes_clutter_in_its_subspace_to_the_float64_floor(method, batches, kind):
    """Direct path and multipath at delays ``< n_range`` lie in the ECA subspace, so the
    residual is zero in exact arithmetic. In float64 ``X w`` carries errors of a few ulp of
    ``surv`` times the condition number of ``X^H X`` (~1 for white noise, ~1e2 for this
    FM-like reference), so the residual-to-input power ratio is ~1e-30..1e-26; a wrong lag,
    edge term or block boundary would leave O(1/N) >= 1e-5 of it."""
    rng = np.random.default_rng(7)
    N = 4000
    if kind == "white":
        ref = cnoise(rng, 2, N)
    else:  # constant envelope, random-walk phase: a low-pass, correlated reference
        ref = np.exp(1j * np.cumsum(rng.standard_normal((2, N)) * 0.7, axis=-1))
    surv = _clutter(rng, ref)
    clean, w = eca(torch.tensor(surv), torch.tensor(ref), 16, batches=batches, method=method)
    assert clean.shape == surv.shape and w.shape == (2, batches, 16)
    ratio = (clean.abs() ** 2).sum(-1) / torch.tensor(np.abs(surv) ** 2).sum(-1)
    assert bool((ratio < 1e-20).all()), ratio
    depth = cancellation_depth_db(torch.tensor(surv), clean)
    assert depth.shape == (2,) and bool((depth > 200).all())


def test_eca_with_noise_leaves_the_noise_minus_its_projection():
    """``surv = clutter + noise``: the residual is ``P_perp noise``, equal to an independent
    least-squares solution, and ``|residual - noise|^2 = |P noise|^2`` is ``sigma^2`` times a
    chi-square of ``2K`` degrees of freedom over 2 (mean ``K sigma^2``, sd ``sqrt(K) sigma^2``)."""
    rng = np.random.default_rng(8)
    N, K, sigma2 = 6000, 16, 0.25
    ref = cnoise(rng, N)
    noise = cnoise(rng, N) * math.sqrt(sigma2)
    surv = _clutter(rng, ref) + noise
    clean, w = eca(torch.tensor(surv), torch.tensor(ref), K)
    X = np.stack([delayed(ref, u) for u in range(K)], axis=-1)
    w_ls = np.linalg.lstsq(X, surv, rcond=None)[0]
    assert rel_err(w[0].numpy(), w_ls) < 1e-9
    assert rel_err(clean.numpy(), surv - X @ w_ls) < 1e-9
    e = clean.numpy()
    assert np.abs(X.conj().T @ e).max() < 1e-9 * np.linalg.norm(X) * np.linalg.norm(e)  # orthogonal
    removed = np.sum(np.abs(e - noise) ** 2) / (K * sigma2)
    assert 0.4 < removed < 1.8  # about -2.4 and +3.2 sd of chi2(32) / 32


def test_eca_diagonal_loading_is_a_ridge_solution():
    """``diagonal_loading = a`` solves ``(X^H X + a mean(diag) I) w = X^H surv``."""
    rng = np.random.default_rng(15)
    N, K, a = 1000, 6, 0.05
    ref, surv = cnoise(rng, N), cnoise(rng, N)
    X = np.stack([delayed(ref, u) for u in range(K)], axis=-1)
    G = X.conj().T @ X
    w_ridge = np.linalg.solve(G + a * np.mean(np.diag(G).real) * np.eye(K), X.conj().T @ surv)
    for method in ("fft", "matmul"):
        clean, w = eca(torch.tensor(surv), torch.tensor(ref), K, method=method, diagonal_loading=a)
        assert rel_err(w[0].numpy(), w_ridge) < 1e-9
        assert rel_err(clean.numpy(), surv - X @ w_ridge) < 1e-9


@pytest.mark.parametrize("N,K,batches", [(3000, 7, 5), (2048, 1, 1), (999, 4, 3), (4096, 12, 2)])
def test_eca_fft_gram_equals_plain_matmul(N, K, batches):
    """The FFT/Toeplitz normal equations (with their edge corrections) against ``X^H X``."""
    rng = np.random.default_rng(9)
    surv, ref = cnoise(rng, 2, 3, N), cnoise(rng, 2, 3, N)
    a, wa = eca(torch.tensor(surv), torch.tensor(ref), K, batches=batches, method="fft")
    b, wb = eca(torch.tensor(surv), torch.tensor(ref), K, batches=batches, method="matmul")
    assert wa.shape == (2, 3, batches, K)
    assert rel_err(wa.numpy(), wb.numpy()) < 1e-9
    assert rel_err(a.numpy(), b.numpy()) < 1e-9


@pytest.mark.parametrize("batches", [1, 4])
def test_eca_matches_pyapril_ecas(batches):
    """``ECAS(ref, surv, [[0, u] for u < K], T, Na=0)`` is ECA(-B) with ``T`` blocks; pyAPRiL too
    takes the previous block's reference for delays crossing a block start."""
    pytest.importorskip("pyapril")
    from pyapril.clutterCancellation import ECAS

    rng = np.random.default_rng(10)
    N, K = 2048, 8
    ref = cnoise(rng, N)
    surv = _clutter(rng, ref, delays=(0, 3), scale=10.0) + cnoise(rng, N)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # np.matrix
        theirs = ECAS(ref, surv, [[0, u] for u in range(K)], batches, 0)
    ours, _ = eca(torch.tensor(surv), torch.tensor(ref), K, batches=batches)
    assert rel_err(ours.numpy(), theirs) < 1e-9


def test_eca_doppler_columns_match_pyapril_ecas():
    """pyAPRiL's Doppler index ``k`` shifts by ``k / (2N)`` cycles per sample (global ``n``); ours
    ``d`` by ``d / B`` per sample of a block of ``B = N / T`` (block-local ``n``, a constant phase
    per column that the projection ignores): ``k = 2 d T``."""
    pytest.importorskip("pyapril")
    from pyapril.clutterCancellation import ECAS

    rng = np.random.default_rng(11)
    N, K, T = 2048, 6, 2
    ref = cnoise(rng, N)
    n = np.arange(N)
    surv = (_clutter(rng, ref, delays=(0, 2), scale=10.0) * np.exp(2j * np.pi * n * T / N)
            + cnoise(rng, N))  # clutter at Doppler bin +1 of the blocks
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        theirs = ECAS(ref, surv, [[2 * d * T, u] for d in (-1, 0, 1) for u in range(K)], T, 0)
    ours, w = eca(torch.tensor(surv), torch.tensor(ref), K, doppler_bins=(-1, 0, 1), batches=T)
    assert w.shape == (T, 3 * K)
    assert rel_err(ours.numpy(), theirs) < 1e-9
    assert float(cancellation_depth_db(torch.tensor(surv), ours)) > 15  # 10^2 clutter vs unit noise


# ---------------------------------------------------------------------------------------------
# NLMS
# ---------------------------------------------------------------------------------------------


def _nlms_loop(surv, ref, K, mu, block, eps=1e-12):
    """Block NLMS written out sample by sample (block = 1: the textbook NLMS)."""
    N = surv.shape[-1]
    w = np.zeros(K, dtype=complex)
    out = np.zeros(N, dtype=complex)
    for start in range(0, N, block):
        grad = np.zeros(K, dtype=complex)
        energy = 0.0
        for n in range(start, min(start + block, N)):
            x = np.array([ref[n - u] if n - u >= 0 else 0.0 for u in range(K)])
            out[n] = surv[n] - x @ w
            grad += x.conj() * out[n]
            energy += np.sum(np.abs(x) ** 2)
        w = w + mu * grad / (eps + energy)
    return out, w


@pytest.mark.parametrize("block", [1, 3, 7, 16, 50])
def test_nlms_equals_a_per_sample_loop(block):
    """Blocks 1 and 3 (< the 5 taps) run on the samples, 7, 16 and 50 by the affine recursion on
    the blocks' normal equations (7 and 16 leave a short last block, done on the samples)."""
    rng = np.random.default_rng(12)
    N, K, mu = 300, 5, 0.7
    ref = cnoise(rng, 2, N)
    surv = _clutter(rng, ref, delays=(0, 1, 3), scale=1.0) + 0.1 * cnoise(rng, 2, N)
    out, w = nlms(torch.tensor(surv), torch.tensor(ref), K, mu, block=block)
    assert out.shape == (2, N) and w.shape == (2, K)
    for i in range(2):
        out_i, w_i = _nlms_loop(surv[i], ref[i], K, mu, block)
        assert rel_err(out[i].numpy(), out_i) < 1e-12
        assert rel_err(w[i].numpy(), w_i) < 1e-12


def test_block_nlms_cancels_a_stationary_direct_path():
    """White unit-power reference, direct path + one multipath (power 1.09) over noise at -40 dB,
    8 taps, blocks of 64, mu = 0.5. Per block the weight error shrinks by about ``1 - mu / K``
    (the normalised block step is ``mu I / K`` for a white reference), ~1e-7 after the 256 blocks
    of the first half; then the residual is the noise plus a misadjustment of order
    ``mu / (2 - mu) / 64`` of it, so the second half's depth is ~40 dB: above 20 dB, and never
    above the noise-floor limit ``10 log10(1.0901 / 1e-4) = 40.4 dB`` (+ noise-power scatter)."""
    rng = np.random.default_rng(13)
    N, K = 2**15, 8
    ref = cnoise(rng, 3, N)
    surv = delayed(ref, 0) + 0.3 * delayed(ref, 3) + 1e-2 * cnoise(rng, 3, N)
    out, w = nlms(torch.tensor(surv), torch.tensor(ref), K, 0.5, block=64)
    half = slice(N // 2, None)
    depth = cancellation_depth_db(torch.tensor(surv[:, half]), out[:, half])
    assert bool((depth > 20).all()) and bool((depth < 40.6).all()), depth
    assert np.abs(w[:, 0].numpy() - 1).max() < 1e-2 and np.abs(w[:, 3].numpy() - 0.3).max() < 1e-2


# ---------------------------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------------------------


def test_bad_input_is_a_config_error():
    rng = np.random.default_rng(14)
    s, r = torch.tensor(cnoise(rng, 256)), torch.tensor(cnoise(rng, 256))
    bad = s.clone()
    bad[10] = complex(float("nan"), 0.0)
    cases = [
        (lambda: ccf_direct(bad, r, 8, [0]), "surveillance samples contain NaN or inf"),
        (lambda: eca(s, torch.where(torch.arange(256) == 3, complex(float("inf"), 0), r), 8),
         "reference samples contain NaN or inf"),
        (lambda: ccf_batches(s[:8], r[:8], 8, 8, 1.0, 1e3), "not longer than the longest delay"),
        (lambda: eca(s[:16], r[:16], 16), "not longer than the longest delay"),
        (lambda: ccf_direct(s, r[:128], 8, [0]), "shapes differ"),
        (lambda: ccf_direct(s, r, 8, [0.5]), "doppler_bins must be a non-empty 1-D sequence of integers"),
        (lambda: ccf_direct(s, r, 8, [0], window=torch.ones(10)), "the window must have shape"),
        (lambda: ccf_batches(s, r, 8, 24, 1.0, 1e3), "does not divide the CPI of 256 samples"),
        (lambda: ccf_batches(s, r, 16, 8, 1.0, 1e3), "batch_len must be an integer >= n_range"),
        (lambda: ccf_batches(s, r, 8, 32, 20.0, 1e3), "exceeds the unambiguous span"),
        (lambda: ccf_batches(s, r, 8, 32, 10.0, 1e3, window="kaiser"), "unknown Doppler window"),
        (lambda: ccf_batches(s, r, 8, 32, 10.0, 1e3, doppler_fft=4), "doppler_fft must be an integer >="),
        (lambda: eca(s, r, 8, batches=3), "3 batches do not divide the CPI of 256 samples"),
        (lambda: eca(s, r, 8, doppler_bins=(0, 1), batches=32), "must exceed its 16 unknowns"),
        (lambda: eca(s, r, 8, doppler_bins=(1,), method="fft"), "handles zero Doppler only"),
        (lambda: eca(s, r, 8, doppler_bins=(0, 0)), "doppler_bins must be distinct"),
        (lambda: eca(s, torch.zeros_like(r), 8), "not positive definite"),
        (lambda: nlms(s, r, 8, 0.0), r"mu must lie in \(0, 2\)"),
        (lambda: nlms(s, r, 8, 2.0), r"mu must lie in \(0, 2\)"),
        (lambda: nlms(s, r, 8, 0.5, block=0), "block must be a positive integer"),
        (lambda: nlms(s, r, 0, 0.5), "n_taps must be a positive integer"),
        (lambda: cancellation_depth_db(s, r[:10]), "shapes differ"),
    ]
    for call, message in cases:
        with pytest.raises(ConfigError, match=message):
            call()
