"""The modified ICMB's online SNR estimate (issue 37): the seed's maximum over particles and its
parametric-bootstrap bias correction (:mod:`pmsr_nn.tbd.snr`).

The statistical checks compare means over independent maps with tolerances of 4 standard errors
(a false failure about once in 16,000 runs of a check)."""

from __future__ import annotations

import math

import pytest
import torch

from pmsr_nn.errors import ConfigError
from pmsr_nn.tbd.likelihood import gather_cells, max_ml_amplitude, ml_amplitude
from pmsr_nn.tbd.maps import MapSpec, Satellite, frame_at_cells
from pmsr_nn.tbd.multibernoulli import MapLikelihood, MBSpec
from pmsr_nn.tbd.run import simulate_and_run
from pmsr_nn.tbd.scene import TBDScene
from pmsr_nn.tbd.snr import bootstrap_ml_amplitude, replica_maxima

LOBE = MapSpec(doppler_cell_hz=10.0).lobe_cells  # the C/A chip's range triangle, 4.9 cells
D, U = 30, 48


def _near(g: torch.Generator, B: int, n: int, centre: tuple[torch.Tensor, torch.Tensor], spread=(3.0, 6.0)):
    """``n`` fractional cells ``(B, n, 1)`` uniform in a box of ``spread`` cells around ``centre``."""
    d = centre[0] + (torch.rand(B, n, generator=g, dtype=torch.float64) - 0.5) * spread[0]
    u = centre[1] + (torch.rand(B, n, generator=g, dtype=torch.float64) - 0.5) * spread[1]
    return d[..., None].float(), u[..., None].float()


@pytest.mark.parametrize("half, B, R", [(2, 40, 60), (None, 16, 24)])
def test_replicas_drawn_on_the_cells_are_whole_map_replicas(half, B, R):
    """The replicas drawn only on the cells the kept states read (one noise value per distinct
    cell) against replicas drawn as whole maps by the map model (:func:`frame_at_cells`) and read
    by :func:`gather_cells`: the largest ML amplitude has the same mean square over the ``B`` maps
    x ``R`` replicas. Half of the states are copies of others: had copies drawn their own noise, their
    maximum would be inflated and the means would differ."""
    g = torch.Generator().manual_seed(4)
    n = 12
    centre = (12 + torch.rand(B, 1, generator=g, dtype=torch.float64), 20 + torch.rand(B, 1, generator=g, dtype=torch.float64))
    d, u = _near(g, B, n // 2, centre)
    d, u = torch.cat([d, d], 1), torch.cat([u, u], 1)  # every state twice
    amp = torch.full((B, 1), math.sqrt(10 ** 0.8), dtype=torch.float64)  # 8 dB
    cell = replica_maxima((1, D, U), d, u, amp, LOBE, half, 1.0, 30, R, g) ** 2  # (R, B, 1)
    maps = frame_at_cells(d[:, :1].double().repeat(R, 1, 1), u[:, :1].double().repeat(R, 1, 1),
                          torch.ones(R * B, 1, dtype=torch.bool), amp.repeat(R, 1), (D, U), 1.0, LOBE, g).abs()
    cv = gather_cells(maps, d.repeat(R, 1, 1), u.repeat(R, 1, 1), LOBE, half)
    whole = (ml_amplitude(cv, 1.0, 30).amax(1).double() ** 2).view(R, B, 1)
    diff = (cell.mean(0) - whole.mean(0)).sum()
    se = math.sqrt(float(((cell.var(0) + whole.var(0)) / R).sum()))
    assert abs(float(diff)) < 4 * se, (float(diff), se)
    assert float(cell.mean()) > 10 ** 0.8  # the maximum over the states is biased up


def _static_estimates(snr_db: float, B: int = 300, seed: int = 0):
    """One 8-10 dB target per map at a random sub-cell position, 400 states in a box around it and
    400 over the whole map (a particle cloud's spread, and births); the seed's estimate and the
    bootstrap's, as powers ``(B,)``."""
    g = torch.Generator().manual_seed(seed)
    amp = torch.full((B, 1), math.sqrt(10 ** (snr_db / 10)), dtype=torch.float64)
    td = 15 + torch.rand(B, 1, 1, generator=g, dtype=torch.float64) - 0.5
    tu = 24 + torch.rand(B, 1, 1, generator=g, dtype=torch.float64) - 0.5
    z = frame_at_cells(td, tu, torch.ones(B, 1, dtype=torch.bool), amp, (D, U), 1.0, LOBE, g).abs()
    dn, un = _near(g, B, 400, (td[:, :, 0], tu[:, :, 0]))
    df, uf = _near(g, B, 400, (torch.full((B, 1), D / 2.0, dtype=torch.float64), torch.full((B, 1), U / 2.0, dtype=torch.float64)),
                   (D - 6.0, U - 6.0))
    d, u = torch.cat([dn, df], 1), torch.cat([un, uf], 1)
    cv = gather_cells(z, d, u, LOBE, 2)
    valid = torch.ones(B, d.shape[1], dtype=torch.bool)
    seed_max = max_ml_amplitude(cv, valid, 1.0, 30, 256).double()[:, 0] ** 2
    boot = bootstrap_ml_amplitude((1, D, U), d, u, cv, valid, LOBE, 2, 1.0, 30, 256, 4, 32, g)[:, 0] ** 2
    return seed_max, boot


@pytest.mark.integration
@pytest.mark.parametrize("snr_db", [8.0, 10.0])
def test_the_bootstrap_removes_part_of_the_maximums_bias_without_overshooting(snr_db):
    """Mean estimated power over 300 maps, in dB against the true SNR: the seed's maximum is biased
    up (beyond 4 standard errors); the bootstrap's is lower than it, paired, beyond 4 standard
    errors, and not below the truth by more than 4. (It removes a part of the bias only, measured
    +1.0 -> +0.5 dB at 8 dB and +0.7 -> +0.3 dB at 10 dB on these draws: the replicas search over
    the 32 kept states, not all 800.)"""
    seed_max, boot = _static_estimates(snr_db)
    B = seed_max.shape[0]
    to_db = 10 / math.log(10)
    true = 10 ** (snr_db / 10)

    def bias_db(p):
        return 10 * math.log10(float(p.mean()) / true), to_db * float(p.std()) / float(p.mean()) / math.sqrt(B)

    b_max, se_max = bias_db(seed_max)
    b_boot, se_boot = bias_db(boot)
    paired = to_db * float((seed_max / seed_max.mean() - boot / boot.mean()).std()) / math.sqrt(B)
    assert b_max > 4 * se_max, (b_max, se_max)
    assert b_max - b_boot > 4 * paired, (b_max, b_boot, paired)
    assert b_boot > -4 * se_boot, (b_boot, se_boot)


def test_unknown_estimator_and_missing_generator_are_refused():
    with pytest.raises(ConfigError, match="snr_estimator must be one of max, bootstrap, got 'median'"):
        MBSpec(estimate_snr=True, snr_estimator="median")
    with pytest.raises(ConfigError, match="snr_replicas and snr_kept_states must be at least 1"):
        MBSpec(snr_replicas=0)
    spec = MBSpec(estimate_snr=True, snr_estimator="bootstrap")
    with pytest.raises(ConfigError, match="needs a generator for its replica maps"):
        MapLikelihood(spec, None, None, LOBE, 1.0, torch.zeros(1))
    MapLikelihood(MBSpec(estimate_snr=True), None, None, LOBE, 1.0, torch.zeros(1))  # the seed's needs none


SATS = (Satellite("SVN2", (-17745.0e3, 1835.5e3, 13077.3e3), (2229.2, -519.2, 2058.0)),
        Satellite("SVN10", (10232.9e3, -15519.5e3, 12420.5e3), (190.2, -2114.0, -1798.6)),
        Satellite("SVN18", (6818.7e3, -6090.4e3, 18620.3e3), (1654.7, -2019.3, -926.3)))


@pytest.mark.slow  # two filters over 32 runs of the seed's scene (about 3 minutes)
def test_bootstrap_estimate_meets_issue_37_on_the_seeds_scene():
    """The seed's scene (8, 9, 10 dB, 5x5 sub-area, the seed's particle budget), 32 runs: the
    bias-corrected estimate averaged over frames 11-16 within 0.5 dB of each map's SNR, and the
    modified ICMB's detected-frame rate over the present frames within 5 points of the ICMB with
    known SNRs on the same maps (issue 37's targets; measured 80.7 % against 81.0 %, and 8.40,
    9.08, 10.06 dB, when this test was written; the seed's estimate gave 70.6 % and 8.73, 9.41,
    10.41 dB on the same maps)."""
    scene = TBDScene(SATS, (8.0, 9.0, 10.0), MapSpec(doppler_cell_hz=10.0))
    out, truth = simulate_and_run(scene, MBSpec(estimate_snr=True, snr_estimator="bootstrap"), 32, 7)
    known, _ = simulate_and_run(scene, MBSpec(), 32, 7)
    est = out.snr_db[:, 10:16].mean((0, 1))
    assert torch.allclose(est, torch.tensor([8.0, 9.0, 10.0], dtype=torch.float64), atol=0.5), est.tolist()
    alive = truth.alive[:, 0]
    rate = lambda o: float(o.best(0.5)[1][:, alive].double().mean())  # noqa: E731
    assert rate(out) >= rate(known) - 0.05, (rate(out), rate(known))
