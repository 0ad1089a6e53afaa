"""Track-before-detect on range-Doppler maps (issue 16): the map model, the likelihood ratio, the
ML amplitude, the multi-Bernoulli filter's stages, and the filter's behaviour on small scenes
(the method kinds on the runner: tests/test_tbd_kinds.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import optimize, special, stats

from pmsr_nn.errors import ConfigError
from pmsr_nn.tbd.detect import DetectSpec, detect, detection_probability
import pmsr_nn.tbd.likelihood as likelihood
from pmsr_nn.tbd.likelihood import (CellValues, bessel_ratio, gather_cells, log_i0e, log_likelihood_ratio,
                                    max_ml_amplitude, ml_amplitude)
from pmsr_nn.tbd.maps import MapGrid, MapSpec, Satellite, power_ratio, range_doppler, simulate_frame, triangle
from pmsr_nn.filters.particle import segmented_resample as _resample
from pmsr_nn.tbd.multibernoulli import BirthBox, MBSpec, MBState, MultiBernoulliTBD
from pmsr_nn.tbd.run import simulate_and_run
from pmsr_nn.tbd.scene import TBDScene

SATS = (Satellite("SVN2", (-17745.0e3, 1835.5e3, 13077.3e3), (2229.2, -519.2, 2058.0)),
        Satellite("SVN10", (10232.9e3, -15519.5e3, 12420.5e3), (190.2, -2114.0, -1798.6)),
        Satellite("SVN18", (6818.7e3, -6090.4e3, 18620.3e3), (1654.7, -2019.3, -926.3)))


def _grid(D=40, U=60, P=1):
    return MapGrid(torch.zeros(P, dtype=torch.float64), torch.zeros(P, dtype=torch.float64), D, U, 60.0, 10.0)


def test_range_doppler_matches_direct_geometry():
    """Excess bistatic range by the cancellation-free form against float64 norms of the full
    distances, and Doppler against a finite difference of the range in time."""
    spec = MapSpec(wavelength_m=0.19)
    tx = torch.tensor([s.position_m for s in SATS], dtype=torch.float64)
    x = torch.tensor([[140e3, -30.0, 2e3, 100.0], [139e3, -45.0, -4e3, 85.0]], dtype=torch.float64)
    rng, dop = range_doppler(x, tx, spec)
    p = torch.stack([x[:, 0], x[:, 2], torch.full_like(x[:, 0], spec.altitude_m)], -1)[:, None]
    direct = (p - tx).norm(dim=-1) + p.norm(dim=-1) - tx.norm(dim=-1)
    assert torch.allclose(rng, direct, atol=1e-6)
    h = 1e-3
    x2 = x.clone()
    x2[:, 0] += h * x[:, 1]
    x2[:, 2] += h * x[:, 3]
    rate = (range_doppler(x2, tx, spec)[0] - rng) / h
    assert torch.allclose(dop, -rate / spec.wavelength_m, atol=1e-3)


def test_log_likelihood_ratio_equals_the_rician_over_rayleigh_density_ratio():
    """Eq. 15 on a handful of cells against scipy's Rice and Rayleigh densities of |z|."""
    g = torch.Generator().manual_seed(3)
    B, M, P, S = 1, 4, 2, 5
    absz = torch.rand((B, M, P, S), generator=g) * 4
    G = torch.rand((B, M, P, S), generator=g)
    amp = torch.tensor([[[1.7, 2.4]]])
    sigma2 = 1.3
    ours = log_likelihood_ratio(CellValues(absz, G), amp, sigma2)
    s = math.sqrt(sigma2 / 2)  # Rician / Rayleigh scale of |z| for complex noise of power sigma2
    z = absz.double().numpy()
    nu = (amp[..., None] * G).double().numpy()
    direct = (stats.rice.logpdf(z, nu / s, scale=s) - stats.rayleigh.logpdf(z, scale=s)).sum(-1)
    np.testing.assert_allclose(ours.numpy(), direct, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_bessel_approximations_against_scipy(dtype):
    """A&S 9.8.1-9.8.4 state relative errors below 2.2e-7 per function: log i0e within 1e-6 and
    I1/I0 within 2e-6 of scipy's double-precision values, float32 rounding included, across
    both branches (the switch at 3.75) and far into the asymptotic range."""
    x = np.concatenate([np.linspace(0.0, 50.0, 100_001), [3.75 - 1e-6, 3.75, 3.75 + 1e-6],
                        np.geomspace(50.0, 1e6, 2_000)])
    xt = torch.tensor(x, dtype=dtype)
    np.testing.assert_allclose(log_i0e(xt).double().numpy(), np.log(special.i0e(x)), rtol=0, atol=1e-6)
    np.testing.assert_allclose(bessel_ratio(xt).double().numpy(), special.i1e(x) / special.i0e(x), rtol=0, atol=2e-6)
    assert float(log_i0e(xt[:1])) == 0.0 and float(bessel_ratio(xt[:1])) == 0.0  # x = 0: I0 = 1, I1 = 0


def test_chunked_gather_and_likelihood_equal_one_chunk(monkeypatch):
    """Chunks of states (cache-sized temporaries) give the values of one pass over all states."""
    g = torch.Generator().manual_seed(8)
    maps = torch.rand((2, 3, 30, 40), generator=g) * 3
    d = torch.rand((2, 50, 3), generator=g) * 29
    u = torch.rand((2, 50, 3), generator=g) * 39
    amp = torch.tensor([1.5, 2.0, 2.5]).view(1, 1, 3).expand(2, 1, 3)
    for half in (2, None):
        whole_cells = gather_cells(maps, d, u, 2.5, half)
        whole = log_likelihood_ratio(whole_cells, amp, 1.2)
        monkeypatch.setattr(likelihood, "LIKELIHOOD_CHUNK_CELLS", 7 * 2 * 3 * 25)  # 7 states per chunk at 5x5
        cells = gather_cells(maps, d, u, 2.5, half)
        assert torch.equal(cells.absz, whole_cells.absz) and torch.equal(cells.G, whole_cells.G)
        assert torch.equal(log_likelihood_ratio(cells, amp, 1.2), whole)
        monkeypatch.undo()


def test_gather_cells_reads_the_subarea_around_the_state_cell():
    maps = torch.arange(2 * 7 * 9, dtype=torch.float32).reshape(1, 2, 7, 9)
    d = torch.tensor([[[3.2, 0.4]]])
    u = torch.tensor([[[4.6, 8.4]]])
    cv = gather_cells(maps, d, u, lobe_cells=2.0, half=1)
    v = cv.absz[0, 0, 0].reshape(3, 3)
    assert torch.equal(v, maps[0, 0, 2:5, 4:7])  # rows 2..4 around round(3.2) = 3, columns 4..6 around 5
    G = cv.G[0, 0, 0].reshape(3, 3)
    rows = torch.arange(2, 5, dtype=torch.float32)[:, None]
    cols = torch.arange(4, 7, dtype=torch.float32)[None]
    assert torch.allclose(G, triangle((cols - 4.6) / 2.0) * torch.sinc(rows - 3.2).abs())
    # map 2's state sits at the corner: cells outside the map carry no response
    G2 = cv.G[0, 0, 1].reshape(3, 3)
    assert bool((G2[0] == 0).all()) and bool((G2[:, 2] == 0).all()) and bool((G2[1:, :2] > 0).all())
    full = gather_cells(maps, d, u, lobe_cells=2.0, half=None)
    assert full.absz.shape[-1] == 7 * 5  # every row, the +-2 columns the triangle reaches


def test_ml_amplitude_maximises_the_exact_likelihood():
    g = torch.Generator().manual_seed(5)
    G = torch.rand((1, 3, 1, 25), generator=g)
    A_true = torch.tensor([0.5, 2.0, 4.0]).view(1, 3, 1, 1)
    noise = torch.view_as_complex(torch.randn((1, 3, 1, 25, 2), generator=g) * math.sqrt(0.5))
    absz = (A_true * G + noise).abs().float()
    cv = CellValues(absz, G)
    ours = ml_amplitude(cv, 1.0, iterations=200)[0, :, 0].double().numpy()
    for m in range(3):
        def nll(a):
            return -float(log_likelihood_ratio(CellValues(absz[:, m:m + 1], G[:, m:m + 1]),
                                               torch.tensor([[[a]]]), 1.0).double())
        best = optimize.minimize_scalar(nll, bounds=(0.0, 20.0), method="bounded", options={"xatol": 1e-7}).x
        assert abs(ours[m] - best) < 2e-3 * max(best, 1.0)
    # the pre-selection of candidates returns the same maximum here as iterating every state
    valid = torch.ones(1, 3, dtype=torch.bool)
    assert torch.allclose(max_ml_amplitude(cv, valid, 1.0, 200, candidates=1), max_ml_amplitude(cv, valid, 1.0, 200, None))


def test_power_ratio_of_simulated_maps_matches_its_analytic_value():
    """Share of a noise-free target's energy inside the sub-area around its nearest cell, over
    2,000 uniformly placed targets, against :func:`power_ratio` (4 Monte Carlo standard errors)."""
    spec = MapSpec(noise_power=1e-30, doppler_cell_hz=10.0)
    grid = _grid(D=101, U=61)
    g = torch.Generator().manual_seed(1)
    n = 2000
    d = 50 + torch.rand(n, generator=g, dtype=torch.float64) - 0.5
    u = 30 + torch.rand(n, generator=g, dtype=torch.float64) - 0.5
    maps = simulate_frame(u[:, None] * 60.0, d[:, None] * 10.0, torch.ones(n, dtype=torch.bool),
                          torch.tensor([300.0]), grid, spec, torch.Generator().manual_seed(2))  # unit amplitude
    power = maps.abs().double() ** 2
    total = power.sum((-1, -2))[:, 0]
    for half in (0, 1, 2, 5):
        cv = gather_cells(power.float().sqrt(), d[:, None, None].float(), u[:, None, None].float(), spec.lobe_cells, half)
        share = (cv.absz.double() ** 2).sum(-1)[:, 0, 0] / total
        se = float(share.std() / math.sqrt(n))
        # the map holds +-50 Doppler cells: the sinc^2 tail beyond them (~0.4%) is missing from `total`
        assert abs(float(share.mean()) - power_ratio(half, spec.lobe_cells) / 0.996) < 4 * se + 2e-3, half
    assert power_ratio(0, spec.lobe_cells) < power_ratio(1, spec.lobe_cells) < power_ratio(2, spec.lobe_cells) < 1


def _run(scene: TBDScene, spec: MBSpec, runs: int, seed: int, detect_spec: DetectSpec | None = None):
    return simulate_and_run(scene, spec, runs, seed, detect_spec)


SMALL = dict(particles_min=500, particles_max=2000, birth_particles=4000)


def test_high_snr_target_is_locked_within_two_frames_with_a_one_cell_subarea():
    """25 dB maps, a 1x1 sub-area, births around the target (+-400 m, +-3 m/s: at this SNR a
    state must sit in the main lobe of every map at once, which a birth over the seed's whole box
    rarely gives within two frames): every run detects from the second frame on."""
    box = BirthBox((139_600.0, 140_400.0), (-400.0, 400.0), (-33.0, -27.0), (97.0, 103.0))
    scene = TBDScene(SATS, (25.0, 25.0, 25.0), MapSpec(doppler_cell_hz=10.0), box, frames=4, appears_frame=1,
                     disappears_frame=4)
    out, truth = _run(scene, MBSpec(subarea_half=0, **SMALL), runs=6, seed=11)
    x, det, _ = out.best(0.5)
    assert bool(det[:, 1:].all())
    err = (x[:, 1:, [0, 2]] - truth.x[:, 1:, 0, [0, 2]]).norm(dim=-1)
    assert float(err.max()) < 300.0  # inside the range triangle's half-width (293 m of path)


@pytest.mark.slow  # a statistical study over many noise-only frames
@pytest.mark.parametrize("estimator", ["max", "bootstrap"])
def test_existence_without_a_target_stays_below_the_threshold(estimator):
    """No target at all, 8-10 dB maps, 24 runs x 20 frames: the measured false-alarm rate of the
    'detected' flag (most probable component above 0.5) must be at most 1% of the frames, with
    the seed's SNR estimate and with the bias-corrected one."""
    scene = TBDScene(SATS, (8.0, 9.0, 10.0), MapSpec(doppler_cell_hz=10.0), frames=20, appears_frame=20,
                     disappears_frame=20, position_m=(140_000.0, 0.0))
    spec = MBSpec(estimate_snr=True, snr_estimator=estimator, **SMALL)
    out, truth = _run(scene, spec, runs=24, seed=21)
    _, det, r = out.best(0.5)
    absent = ~truth.alive[:, 0]
    rate = float(det[:, absent].double().mean())
    assert rate <= 0.01, rate
    assert float(r[:, absent].max()) < 0.999  # nothing is confirmed


def test_update_order_follows_the_snrs_it_uses():
    scene = TBDScene(SATS, (10.0, 8.0, 9.0), MapSpec(doppler_cell_hz=10.0), frames=3, appears_frame=1, disappears_frame=3)
    out, _ = _run(scene, MBSpec(update="ascending", **SMALL), runs=2, seed=1)
    assert out.order[0, 0].tolist() == [1, 2, 0]
    out, _ = _run(scene, MBSpec(update="descending", **SMALL), runs=2, seed=1)
    assert out.order[0, 0].tolist() == [0, 2, 1]


def test_bernoulli_update_matches_the_closed_form():
    """One component of three particles with known ratios: r' = r m / (1 - r + r m), w' ~ w L."""
    spec = MBSpec()
    f = MultiBernoulliTBD(spec, BirthBox(), 4.9, torch.eye(4, dtype=torch.float64), torch.zeros(4, 2, dtype=torch.float64))
    w = torch.tensor([[0.2, 0.3, 0.5]], dtype=torch.float64)
    st = MBState(torch.zeros(1, 3, 4, dtype=torch.float64), w.log(), torch.zeros(1, 3, dtype=torch.int64),
                 torch.tensor([[0.3, 0.0]], dtype=torch.float64))
    L = torch.tensor([[4.0, 0.5, 2.0]], dtype=torch.float64)
    new = f._bernoulli_update(st, L.log())
    m = float((w * L).sum())
    assert math.isclose(float(new.r[0, 0]), 0.3 * m / (1 - 0.3 + 0.3 * m), rel_tol=1e-12)
    assert torch.allclose(new.logw.exp(), w * L / m)
    assert float(new.r[0, 1]) == 0.0


def test_resampling_gives_each_component_its_count_from_its_own_particles():
    g = torch.Generator().manual_seed(0)
    comp = torch.tensor([[1, 0, 2, 1, 0, 3, 1]])  # slot 2 is inactive below; 3 = padding (Q = 3)
    x = torch.arange(7, dtype=torch.float64).view(1, 7, 1).expand(1, 7, 4).clone()
    logw = torch.tensor([[0.5, 0.25, 1.0, 0.25, 0.75, 0.0, 0.25]], dtype=torch.float64).log()
    active = torch.tensor([[True, True, False]])
    counts = torch.tensor([[3, 5, 0]])
    xn, cn, lw = _resample(x, logw, comp, active, counts, g)
    assert cn[0].tolist() == [0] * 3 + [1] * 5
    src = xn[0, :, 0].long()
    assert all(int(comp[0, s]) == int(c) for s, c in zip(src, cn[0]))
    assert torch.allclose(lw.exp()[0, :3], torch.full((3,), 1 / 3, dtype=torch.float64))
    # systematic: over many draws component 1's particles are picked in proportion to their weights
    picks = torch.zeros(7)
    for i in range(300):
        xn, cn, _ = _resample(x, logw, comp, active, torch.tensor([[1, 4, 0]]), torch.Generator().manual_seed(i))
        for s, c in zip(xn[0, :, 0].long(), cn[0]):
            if int(c) == 1:
                picks[int(s)] += 1
    frac = picks[[0, 3, 6]] / picks.sum()
    assert torch.allclose(frac, torch.tensor([0.5, 0.25, 0.25]), atol=0.02)


def test_roughening_jitters_each_component_by_its_own_spread():
    """Gordon's roughening ``K (max - min) L^(-1/4)`` per component and coordinate: two components of
    different spreads and counts, the jitter's sample variance inside its chi-square interval
    (99.9 %), the padding untouched; K = 0 (the default, the seed's filter) draws nothing."""
    K = 0.2
    f = MultiBernoulliTBD(MBSpec(roughening=K), BirthBox(), 4.9, torch.eye(4, dtype=torch.float64),
                          torch.zeros(4, 2, dtype=torch.float64))
    L0, L1, pad = 4000, 1000, 10
    base = torch.zeros(1, L0 + L1 + pad, 4, dtype=torch.float64)
    base[0, :L0] = torch.linspace(-50.0, 50.0, L0)[:, None] * torch.tensor([1.0, 0.01, 2.0, 0.02], dtype=torch.float64)
    base[0, L0:L0 + L1] = torch.linspace(0.0, 10.0, L1)[:, None]
    comp = torch.tensor([[0] * L0 + [1] * L1 + [2] * pad])  # Q = 2: slot 2 is the padding
    out = f._roughen(base, comp, 2, torch.Generator().manual_seed(5))
    jitter = out - base
    assert bool((jitter[0, L0 + L1:] == 0).all())
    for sl, spread, L in ((slice(0, L0), torch.tensor([100.0, 1.0, 200.0, 2.0]), L0), (slice(L0, L0 + L1),
                                                                                      torch.full((4,), 10.0), L1)):
        sd = K * spread.to(torch.float64) * L ** -0.25
        ratio = (jitter[0, sl] ** 2).sum(0) / sd ** 2  # chi-square with L degrees of freedom per coordinate
        lo, hi = stats.chi2.ppf([0.0005, 0.9995], L)
        assert bool(((ratio > lo) & (ratio < hi)).all()), (ratio / L).tolist()
    plain = MultiBernoulliTBD(MBSpec(), BirthBox(), 4.9, torch.eye(4, dtype=torch.float64),
                              torch.zeros(4, 2, dtype=torch.float64))
    st = MBState(base, torch.zeros(1, L0 + L1 + pad, dtype=torch.float64), comp, torch.tensor([[0.6, 0.3]],
                                                                                               dtype=torch.float64))
    a = plain._resample(st, torch.Generator().manual_seed(5))
    kept = a.comp[0] < 2
    assert bool((a.x[0, kept][:, None] == base[0][None]).all(-1).any(-1).all())  # copies of particles, no jitter
    with pytest.raises(ConfigError, match="roughening must be a finite number >= 0"):
        MBSpec(roughening=-0.1)


def _two_components(r_weak: float):
    """A strong component (slot 0) and a weaker one (slot 1), 10 particles each, unit weights."""
    x = torch.zeros(1, 20, 4, dtype=torch.float64)
    comp = torch.tensor([[0] * 10 + [1] * 10])
    logw = torch.full((1, 20), -math.log(10), dtype=torch.float64)
    return MBState(x, logw, comp, torch.tensor([[0.99, r_weak, 0.0]], dtype=torch.float64))


@pytest.mark.parametrize("own_nats, kept", [(8.0, True), (1.0, False)])
def test_a_component_sharing_one_map_with_a_stronger_one_is_a_ghost_unless_its_other_maps_hold_evidence(own_nats, kept):
    """Two maps; the weaker component's mean shares map 0's cells with the stronger one's and not
    map 1's. The ``shared`` rule drops it whatever it saw; the ``evidence`` rule keeps it where map 1,
    the one it shares with no stronger component, gives it ``own_nats`` above ``ghost_evidence``
    (3 nats). Two components sharing both maps merge under either rule."""
    d = torch.tensor([[[10.0, 20.0], [10.5, 30.0], [0.0, 0.0]]])  # (B, Q, P): Doppler rows
    u = torch.tensor([[[40.0, 50.0], [41.0, 60.0], [0.0, 0.0]]])  # range columns (lobe 4.9)
    evidence = torch.tensor([[[9.0, 9.0], [9.0, own_nats], [0.0, 0.0]]], dtype=torch.float64)
    make = lambda rule: MultiBernoulliTBD(MBSpec(ghost_rule=rule), BirthBox(), 4.9, torch.eye(4, dtype=torch.float64),
                                          torch.zeros(4, 2, dtype=torch.float64))
    shared = make("shared")._prune_merge(_two_components(0.6), (d, u))
    assert float(shared.r[0, 1]) == 0.0 and float(shared.r[0, 0]) == pytest.approx(0.99)
    ev = make("evidence")._prune_merge(_two_components(0.6), (d, u), evidence)
    assert (float(ev.r[0, 1]) == pytest.approx(0.6)) is kept and float(ev.r[0, 0]) == pytest.approx(0.99)
    both = (d.clone(), u.clone())
    both[0][0, 1, 1], both[1][0, 1, 1] = 20.3, 50.5  # now near in both maps: one target, merged
    merged = make("evidence")._prune_merge(_two_components(0.6), both, evidence)
    assert float(merged.r[0, 1]) == 0.0 and float(merged.r[0, 0]) == pytest.approx(0.999)  # r_max


@pytest.mark.slow  # a statistical study over frames and SNRs
def test_snr_estimate_converges_to_the_truth(request):
    """The online estimate of each map's SNR, averaged over frames 11-16 and 8 runs, within 1 dB."""
    scene = TBDScene(SATS, (8.0, 9.0, 10.0), MapSpec(doppler_cell_hz=10.0))
    out, truth = _run(scene, MBSpec(estimate_snr=True, particles_min=2000, particles_max=10_000, birth_particles=10_000),
                      runs=8, seed=31)
    est = out.snr_db[:, 10:16].mean((0, 1))
    assert torch.allclose(est, torch.tensor([8.0, 9.0, 10.0], dtype=torch.float64), atol=1.0), est.tolist()


def test_detection_probability_matches_simulated_peaks():
    """Threshold detection of single targets at uniform offsets: the fraction whose own cell (the
    nearest) is detected against :func:`detection_probability` (4 binomial standard errors)."""
    spec = MapSpec(doppler_cell_hz=10.0)
    grid = _grid(D=41, U=61)
    n = 3000
    g = torch.Generator().manual_seed(4)
    d = 20 + torch.rand(n, generator=g, dtype=torch.float64) - 0.5
    u = 30 + torch.rand(n, generator=g, dtype=torch.float64) - 0.5
    maps = simulate_frame(u[:, None] * 60.0, d[:, None] * 10.0, torch.ones(n, dtype=torch.bool), torch.tensor([6.0]),
                          grid, spec, torch.Generator().manual_seed(5))
    power = maps.abs() ** 2
    thr = math.log(1e3)
    own = power[torch.arange(n), 0, d.round().long(), u.round().long()] > thr
    pd = float(detection_probability(torch.tensor([6.0]), 1e-3, spec.lobe_cells)[0])
    assert abs(float(own.double().mean()) - pd) < 4 * math.sqrt(pd * (1 - pd) / n)
    peaks = detect(maps[:50], 1.0, 1e-3, spec.lobe_cells)
    assert peaks.d.shape[:2] == (50, 1) and bool(peaks.valid.any())


def test_detectors_false_alarm_rate_per_cell_is_the_stated_pfa():
    """Noise-only maps: the share of cells reported as detections by the OS-CFAR and by the
    known-noise threshold, against Pfa = 1e-3 less the local-maximum thinning (a cell above the
    threshold loses to one of its 32 neighbours with probability ~ 32 Pfa / 2), within 4 binomial
    standard errors."""
    g = torch.Generator().manual_seed(8)
    maps = torch.view_as_complex(torch.randn(20, 3, 57, 288, 2, generator=g) * math.sqrt(0.5))
    n = maps.numel()
    for det in ("os_cfar", "known_noise"):
        peaks = detect(maps, 1.0, 1e-3, MapSpec().lobe_cells, DetectSpec(pfa=1e-3, detector=det))
        rate = float(peaks.valid.sum()) / n
        assert abs(rate - 1e-3 * (1 - 16e-3)) < 4 * math.sqrt(1e-3 / n), (det, rate)
