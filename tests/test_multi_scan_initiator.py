"""The multi-scan initiator (pmsr_nn.trackers.multi_scan_initiator.MultiScanInitiator), against
references that do not run its code:

* the started track is the linear-Gaussian posterior of the chain's state at its last scan, from
  the joint Gaussian of the states of the three scans written out here (prior once, the motion
  model's transitions, each candidate's likelihood);
* a straight-line target seen by the Access geometry (three transmitters, one receiver, range and
  Doppler) over three scans starts exactly one track, at the third scan, near it;
* candidates scattered at random start tracks as often as the gate's volume says: two scans at
  the rate computed from the chi-square ellipsoid's volume, three scans (expected count computed,
  far below one) none;
* a wrong number of scans is refused in one line; ``init_scans`` and its gate are options of the
  kinds that start their own tracks (refusals: tests/faults/cases.py).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch
import yaml

from pmsr_nn.cli import main
from pmsr_nn.errors import ConfigError
from pmsr_nn.filters.gaussian import Gaussian
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.loading import load_any
from pmsr_nn.trackers.gating import gate_threshold
from pmsr_nn.trackers.multi_scan_initiator import MultiScanInitiator
from pmsr_nn.trackers.spherical_initiator import SphericalInitiator
from test_spherical_initiator import CV_POS, CV_VEL, access_model, access_study, detections, first_row_tracks

F64 = torch.float64
PLANE = SimpleNamespace(pos_idx=CV_POS, vel_idx=CV_VEL)  # all the initiator reads of a model besides the base
PV = list(CV_POS) + list(CV_VEL)


def cv(dt: float, q: float) -> tuple[torch.Tensor, torch.Tensor]:
    """F and a full-rank Q (continuous white acceleration of PSD q) of the 2-D CV state (x, vx, y, vy)."""
    f = torch.tensor([[1.0, dt], [0.0, 1.0]], dtype=F64)
    qb = q * torch.tensor([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]], dtype=F64)
    return torch.block_diag(f, f), torch.block_diag(qb, qb)


class Given:
    """A stand-in single-scan initiator: hands back the candidates of each scan in turn
    (``scans``: a list of (Gaussian (B, G, 4), real (B, G)))."""

    def __init__(self, scans, velocity_sd_mps: float):
        self.scans, self.velocity_sd_mps, self.k = list(scans), velocity_sd_mps, 0

    def check(self, model, what: str) -> None:
        pass

    def begin(self, B, F=None, Q=None) -> None:
        self.k = 0

    def initiate(self, z, unused, model, n, other_sd, **where):
        self.k += 1
        return self.scans[self.k - 1]


def run(ini: MultiScanInitiator, B: int, K: int, F: torch.Tensor, Q: torch.Tensor):
    """The initiator over ``K`` scans; the tracks started at each."""
    ini.begin(B, F, Q)
    z, unused = torch.zeros(B, 3, 1, 2, dtype=F64), torch.ones(B, 3, 1, dtype=torch.bool)
    return [ini.initiate(z, unused, PLANE, 4, torch.ones(4, dtype=F64)) for _ in range(K)]


def spd(gen: torch.Generator, scale: torch.Tensor) -> torch.Tensor:
    """A random symmetric positive-definite 4x4 information matrix, entries of order 1/scale^2."""
    A = torch.randn(4, 4, generator=gen, dtype=F64)
    Y = A @ A.T + 0.5 * torch.eye(4, dtype=F64)
    return Y / (scale[:, None] * scale[None, :])


def test_the_started_track_is_the_chains_linear_gaussian_posterior():
    gen = torch.Generator().manual_seed(3)
    F, Q = cv(1.0, 4.0)
    v = 20.0
    prior = torch.diag(torch.tensor([0.0, v**-2, 0.0, v**-2], dtype=F64))  # the base's velocity prior N(0, v^2)
    truth = torch.tensor([1000.0, 30.0, -2000.0, -10.0], dtype=F64)
    scale = torch.tensor([300.0, 6.0, 300.0, 6.0], dtype=F64)
    Ys, ys, cands, x = [], [], [], truth
    for k in range(3):
        Y = spd(gen, scale)
        m = x + 0.3 * scale * torch.randn(4, generator=gen, dtype=F64)  # a noisy look at the state
        Ys.append(Y)
        ys.append(Y @ m)
        P = torch.linalg.inv(Y + prior)  # the candidate: this scan's likelihood times the prior
        cands.append((Gaussian((P @ (Y @ m)).view(1, 1, 4), P.view(1, 1, 4, 4)), torch.ones(1, 1, dtype=torch.bool)))
        x = F @ x
    ini = MultiScanInitiator(Given(cands, v), scans=3, gate_probability=1 - 1e-12)
    out = run(ini, 1, 3, F, Q)
    assert [int(r.sum()) for _, r in out] == [0, 0, 1]
    g = out[2][0]
    # the joint Gaussian of (x0, x1, x2) in information form: prior and likelihood on each state,
    # the transitions x_{t+1} = F x_t + w, w ~ N(0, Q)
    Qi = torch.linalg.inv(Q)
    L = torch.zeros(12, 12, dtype=F64)
    eta = torch.zeros(12, dtype=F64)
    L[:4, :4] += prior
    for t in range(3):
        L[4 * t:4 * t + 4, 4 * t:4 * t + 4] += Ys[t]
        eta[4 * t:4 * t + 4] += ys[t]
    for t in range(2):
        a, b = slice(4 * t, 4 * t + 4), slice(4 * t + 4, 4 * t + 8)
        L[a, a] += F.T @ Qi @ F
        L[a, b] -= F.T @ Qi
        L[b, a] -= Qi @ F
        L[b, b] += Qi
    C = torch.linalg.inv(L)
    mean, cov = (C @ eta)[8:], C[8:, 8:]
    # two routes to one posterior, float64: agreement to ~1e-12 relative (condition numbers ~1e5)
    assert torch.allclose(g.x[0, 0], mean, rtol=0, atol=1e-7 * float(scale.max()))
    assert torch.allclose(g.P[0, 0], cov, rtol=1e-8, atol=1e-10 * float(cov.abs().max()))


def test_a_straight_line_target_over_three_scans_starts_one_track_at_the_third():
    model = access_model()
    F, Q = cv(1.0, 1.0)
    start = torch.tensor([-25000.0, 200.0, -20000.0, 244.1], dtype=F64)
    ini = MultiScanInitiator(SphericalInitiator(), scans=3)
    ini.begin(1, F, Q)
    started, x = [], start
    for k in range(4):
        z = detections(model, x.view(1, 4))  # (1, 3, 1, 2): the target at every pair, no noise
        g, real = ini.initiate(z, torch.ones(1, 3, 1, dtype=torch.bool), model, 4, torch.ones(4, dtype=F64))
        started.append((g, real))
        x = F @ x
    # scans 0 and 1 have no chain of three yet; scan 3's candidate shares no chain with a started
    # track (the chain of scans 0-2 started one, so scans 1-3 hold its candidates of scans 1, 2)
    assert [int(r.sum()) for _, r in started] == [0, 0, 1, 0]
    g = started[2][0]
    x2 = F @ F @ start
    # noise-free data: the error is the velocity prior's pull only, well inside the covariance
    err = (g.x[0, 0] - x2)[PV]
    d2 = err @ torch.linalg.solve(g.P[0, 0][PV][:, PV], err)
    assert float(d2) < gate_threshold(0.999, 4)


def scattered(gen, B: int, N: int, box: torch.Tensor, margin: torch.Tensor, P: torch.Tensor):
    """``N`` candidates per run uniform in ``[margin, box - margin]`` per entry (x, vx, y, vy; the
    velocity boxes centred on 0), all with covariance ``P``."""
    lo, hi = margin, box - margin
    u = torch.rand(B, N, 4, generator=gen, dtype=F64)
    x = lo + u * (hi - lo)
    x[..., list(CV_VEL)] -= box[list(CV_VEL)] / 2
    return Gaussian(x, P.expand(B, N, 4, 4).clone()), torch.ones(B, N, dtype=torch.bool)


def test_scattered_candidates_start_tracks_at_the_rate_the_gate_volume_gives():
    gen = torch.Generator().manual_seed(11)
    F, Q = cv(1.0, 1.0)
    P = torch.diag(torch.tensor([300.0, 5.0, 300.0, 5.0], dtype=F64) ** 2)  # candidate covariance (prior in)
    box = torch.tensor([1e5, 400.0, 1e5, 400.0], dtype=F64)  # x, vx, y, vy widths (velocities +-200 m/s)
    volume = float(box.prod())
    p_gate = 0.999
    gamma = gate_threshold(p_gate, 4)
    S = (F @ P @ F.T + Q + P)[PV][:, PV]
    # the gate: the ellipsoid d^T S^-1 d <= gamma in 4-D, volume (pi^2 / 2) gamma^2 sqrt(det S)
    v_gate = math.pi**2 / 2 * gamma**2 * math.sqrt(float(torch.linalg.det(S)))
    reach = torch.empty(4, dtype=F64)
    reach[PV] = (gamma * torch.diagonal(S)).sqrt()  # the gate's half-widths per state entry
    inner = torch.tensor([200.0, 0.0, 200.0, 0.0], dtype=F64) + reach + 1.0  # drift over a scan + gate
    B, N = 2000, 100
    # two scans: scan 0's candidates drawn inside so every gate lies in scan 1's box: the chance a
    # pair passes is exactly v_gate / volume
    first = scattered(gen, B, N, box, inner, P)
    second = scattered(gen, B, N, box, torch.zeros(4, dtype=F64), P)
    out = run(MultiScanInitiator(Given([first, second], 20.0), scans=2, gate_probability=p_gate), B, 2, F, Q)
    mean = N * N * v_gate / volume  # expected passing pairs per run (~0.09; two sharing a candidate ~1e-4)
    count = float(out[1][1].sum())
    assert out[0][1].numel() == 0
    # Poisson count over B runs: within 4 standard deviations
    assert abs(count - B * mean) <= 4 * math.sqrt(B * mean), (count, B * mean)
    # three scans, the same clutter density: a pair's fused Gaussian, predicted, must also meet a
    # third candidate; expected chains = N^3 (v_gate / volume) (v_gate3 / volume) per run
    Pf = torch.linalg.inv(torch.linalg.inv(F @ P @ F.T + Q) + torch.linalg.inv(P) - torch.diag(
        torch.tensor([0.0, 20.0**-2, 0.0, 20.0**-2], dtype=F64)))
    S3 = (F @ Pf @ F.T + Q + P)[PV][:, PV]
    v_gate3 = math.pi**2 / 2 * gamma**2 * math.sqrt(float(torch.linalg.det(S3)))
    B3 = 20
    expected = B3 * N**3 * (v_gate / volume) * (v_gate3 / volume)
    assert expected < 1e-2  # so a correct initiator starts none here (P(any) < 1 %)
    scans = [scattered(gen, B3, N, box, torch.zeros(4, dtype=F64), P) for _ in range(3)]
    out3 = run(MultiScanInitiator(Given(scans, 20.0), scans=3, gate_probability=p_gate), B3, 3, F, Q)
    assert sum(int(r.sum()) for _, r in out3) == 0


@pytest.mark.parametrize("scans", [0, 1])
def test_fewer_than_two_scans_is_refused(scans):
    with pytest.raises(ConfigError, match="scans >= 2"):
        MultiScanInitiator(SphericalInitiator(), scans=scans)


# -- the options, end to end -------------------------------------------------------------------------

def two_targets(tmp_path, options: dict, kind: str = "s_msjpda", **over):
    """The Access geometry and noise, two targets 10 km apart, Pd 1, no clutter, 2 runs of 8 scans
    (tests/test_spherical_initiator.py's end-to-end scene)."""
    path = access_study(tmp_path, [{"name": "S", "kind": kind, "options": options}],
                        mc_runs=2, block_runs=2, warmup_steps=2,
                        detections={"pd": 1.0, "components": ["range", "doppler"],
                                    "clutter": {"per_scan": 0, "model": "fixed", "range_m": [0.0, 150000.0],
                                                "doppler_hz": [-250.0, 250.0]}},
                        cases=[{"name": "c", "formation": {"count": 2, "centre_m": [-25000.0, -20000.0],
                                                           "velocity_mps": [200.0, 244.1], "spacing_m": 10000.0}}],
                        **over)
    data = yaml.safe_load(path.read_text())
    data["world"]["scans"] = 8
    path.write_text(yaml.safe_dump(data))
    return path


def test_s_msjpda_with_three_scan_initiation_confirms_one_track_per_target_a_scan_after_the_chain(tmp_path):
    """Both targets' candidates chain over scans 0-2, start a tentative track at scan 2 and are
    confirmed at scan 3 (2 of 3, the initiation scan counting): first track at scan 3, nothing else."""
    path = two_targets(tmp_path, {"initiation": "detections", "init_scans": 3})
    est, ts = first_row_tracks(path)
    B = est.exists.shape[0]
    assert ts.tracks_per_target.tolist() == [[1.0, 1.0]] * B and ts.false_tracks.tolist() == [0.0] * B
    assert ts.scans_to_first_track.tolist() == [[3.0, 3.0]] * B
    assert bool(est.exists[:, 3:].all()) and not bool(est.exists[:, :3].any())


@pytest.mark.parametrize("kind, options, message", [
    ("s_msjpda", {"initiation": "detections", "init_scans": 4}, "option init_scans must be an integer in [1, 3]"),
    ("s_msjpda", {"initiation": "detections", "init_scans": 0}, "option init_scans must be an integer in [1, 3]"),
    ("s_msjpda", {"initiation": "detections", "init_scan_gate_probability": 0.9},
     "init_scan_gate_probability are read only with init_scans: 2 | 3"),
    ("bp", {"init_scans": 4}, "option init_scans must be an integer in [1, 3]"),
])
def test_bad_init_scans_are_one_line_errors_naming_the_row_and_write_nothing(tmp_path, capsys, kind, options, message):
    path = two_targets(tmp_path, options, kind)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'S'" in err[0] and message in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("kind, options, message", [
    ("bp", {"init_scans": 3}, "option init_scans is read only without azimuth"),
    ("s_msjpda", {"initiation": "detections", "init_scans": 2, "init_scan_candidates": "greedy"},
     "option init_scan_candidates is read only without azimuth"),
])
def test_with_azimuth_options_that_would_go_unread_are_refused(tmp_path, capsys, kind, options, message):
    path = two_targets(tmp_path, options, kind)
    data = yaml.safe_load(path.read_text())
    data["detections"]["components"] = ["range", "doppler", "azimuth"]
    data["noise"]["azimuth_deg"] = 1.0
    path.write_text(yaml.safe_dump(data))
    assert main(["evaluate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "method 'S'" in err[0] and message in err[0], err
    assert not (tmp_path / "out").exists()


def test_not_exclusive_the_spherical_initiator_hands_on_every_consistent_combination():
    """Noise-free detections of two targets 2 km apart: the greedy selection gives one combination
    per target; not exclusive, every combination that passes the gate, counted here by brute
    force over the 2^3 combinations with the initiator's own fit of each alone (the true two
    among them), the smallest chi-square first."""
    model = access_model()
    truth = torch.tensor([[-25000.0, 200.0, -20000.0, 244.1], [-23000.0, 200.0, -21000.0, 244.1]], dtype=F64)
    z = detections(model, truth)
    unused = torch.ones(1, 3, 2, dtype=torch.bool)
    greedy = SphericalInitiator()
    every = SphericalInitiator(exclusive=False)
    assert int(greedy.initiate(z, unused, model, 4, torch.ones(4, dtype=F64))[1].sum()) == 2
    combos, chi2, _, _ = every.select(z, unused, model, 4)
    passing = 0
    for a in range(2):
        for b in range(2):
            for c in range(2):
                one = torch.zeros(1, 3, 2, dtype=torch.bool)
                one[0, 0, a] = one[0, 1, b] = one[0, 2, c] = True
                passing += int(greedy.select(z, one, model, 4)[0].shape[1])
    real = (combos[0] >= 0).any(-1)
    assert int(real.sum()) == passing >= 2
    assert bool((chi2[0, real].diff() >= 0).all())  # the best first
    own = combos[0, real]
    assert [0, 0, 0] in own.tolist() and [1, 1, 1] in own.tolist()


@pytest.mark.parametrize("options, scans, exclusive", [
    ({}, None, True),  # init_scans 1: today's single-scan initiator itself
    ({"init_scans": 3}, 3, False),
    ({"init_scans": 2, "init_scan_candidates": "greedy", "init_scan_gate_probability": 0.99}, 2, True),
])
def test_the_rows_options_pick_the_initiator(tmp_path, options, scans, exclusive):
    from pmsr_nn.methods.track_management import management

    path = two_targets(tmp_path, {"initiation": "detections", **options})
    setup = prepare(load_any(path))
    ini = management(setup.methods[0], setup.cases[0].sensing).initiator
    if scans is None:
        assert type(ini) is SphericalInitiator and ini == SphericalInitiator()
    else:
        assert isinstance(ini, MultiScanInitiator) and ini.scans == scans
        assert ini.gate_probability == options.get("init_scan_gate_probability", 0.999)
        ini = ini.base
    assert ini.exclusive is exclusive
