"""Multi-sensor SMC-PHD filter in the Cartesian state of a motion model, batched over runs x particles.

The single-plane filter of :mod:`.phd` tracks one pair's (bistatic range, range-rate); this one
tracks targets in the motion model's own state (e.g. CA ``[x, vx, ax, y, vy, ay]``, SI units) and
reads every transmitter-receiver pair's detections. The PHD is a weighted particle set ``x (B, M,
n)``, ``w (B, M)`` (runs ``B`` padded to the largest particle count with weight 0) whose weights
sum to the expected number of targets. One scan:

1. **predict**: every particle moves with the motion model, ``x <- F x + L eps`` (``L L^T = Q(dt,
   q)``); weights x ``p_S``;
2. **birth** (measurement-driven, as :mod:`.phd`): each detection of the *previous* scan whose
   (bistatic range, azimuth) fixes a position (:meth:`~.fix_initiator.FixInitiator.fixes`: the
   position and its covariance ``H^-1 R H^-T``) seeds ``particles_per_birth`` particles: position
   from ``N(fix, cov)``, velocity from the prior ``N(0, birth_velocity_sd^2 I)`` conditioned on the
   detection's own rate (range-rate or Doppler: one row linear in velocity at a known position),
   other entries (acceleration) from ``N(0, other_sd^2)`` (the scenario's initiation prior); then
   moved one step. The birth mass ``birth_rate`` is shared equally among the seeds' particles;
3. **update**, the iterated corrector: one standard PHD update per pair in turn (pair ``s``'s
   ``Pd``, clutter intensity ``kappa_s`` per unit of its measurement space and Gaussian likelihood
   ``g_s(z | x)`` of the wrapped residual ``z - h_s(x)``, diagonal ``R``):
   ``w_i <- (1 - Pd) w_i + sum_j Pd g_ij w_i / (kappa_s + sum_l Pd g_lj w_l)``
   (:func:`~.phd.correct`). A pair's likelihood is formed only for the particle-detection pairs
   whose bistatic-range residual leaves its exponent above -700 (a term below that, under 1e-304,
   is set to 0 either way): the detections sorted in range, each particle reads those inside its window
   (:meth:`CartesianPHD.weighted_likelihood`). The order of the pairs matters (Mahler's caveat of the iterated
   corrector): a target the *last* pair missed keeps only ``1 - Pd`` of its mass (0.11 at Pd 0.9,
   one scan in ten), one an earlier pair missed is restored by the next. Steps 4 and 5 therefore
   decide and budget per cluster, not by the final mass;
4. **estimates**: the gated weighted k-means of :func:`~.phd.cluster` in position, seeded by the
   detection partitions of every pair's update (the mass, mean and position spread each detection
   took), heaviest first while at least ``estimate_mass``. A centre's metric is its seed's
   position spread plus ``cluster_sd_m^2`` per axis (gate: chi-square of ``gate_probability``, 2
   degrees of freedom), so a newborn's cloud (a single fix's cross-range deviation is the
   azimuth's, hundreds of metres) is one cluster, not several, while an established target gates
   at a few of its deviations; two seeds are one target inside the gate of their summed spreads.
   Every cluster so seeded is an estimate (its weighted mean and spread in the full state),
   whatever mass the last pair's miss left it;
5. **resample** (systematic, per cluster: ``particles_per_target`` per unit of mass, at least
   ``particles_per_target``, so a target the last pair missed is not cut to a tenth of its
   particles; the particles of no cluster (births, clutter) per unit of their mass, at least
   ``particles_per_birth``; each cluster's mass kept), then **regularise** (Musso, Oudjane & Le
   Gland 2001): each particle of a cluster moves by ``h N(0, P_c)``, ``P_c`` the cluster's
   weighted spread, ``h = regularisation x (4 / (n + 2))^(1 / (n + 4)) N_c^(-1 / (n + 4))`` with
   ``N_c`` the cluster's particles (``regularisation`` 1: Musso's bandwidth for a Gaussian
   density). The scenario's process noise may be far too small to keep a resampled cloud diverse
   (the FITEE recipe's jerk PSD of 1e-7 m^2/s^5 moves a particle by under a millimetre per scan):
   without it the copies of a few particles follow one deterministic path, with it each scan
   forgets part of what the cloud learnt. On evaluate/shared_drones.yaml (seed 1, 2 runs) the
   median distance from a target to its estimate was 39 m without (first 300 scans), 12.5 m at
   0.5 (520 scans) and 17 m at 1 (420 scans).

The expected number is also carried by the recursion's formulas (:attr:`~.phd.PHDState.expected`),
so a test can hold the particle weights to it after every step.

Shapes: ``B`` runs, ``K`` scans, ``S`` pairs, ``J`` detections per pair and scan (padded), ``M``
particles per run, ``C`` clusters, ``n`` state dimension, ``d`` measurement components per pair.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.particle import segmented_resample
from ..measurements import MeasurementModel, wrap_angle
from ..motion import KinematicModel
from ..rng import standard_normal
from .gating import gate_threshold, inside_gate, mahalanobis, whitened_d2, whitening
from .fix_initiator import FixInitiator
from .initiators import rate_component
from .phd import PHDEstimates, PHDState, check_phd_settings, cluster, correct


@dataclass(frozen=True)
class CartesianPHDSpec:
    """Settings of the filter (module docstring); deviations in SI units."""

    particles_per_target: int = 2000
    particles_per_birth: int = 200
    survival: float = 0.99
    birth_rate: float = 0.05
    birth_velocity_sd_mps: float = 20.0
    estimate_mass: float = 0.5
    cluster_sd_m: float = 30.0
    gate_probability: float = 0.999
    kmeans_iterations: int = 1
    regularisation: float = 0.5

    @property
    def gate(self) -> float:
        """The clustering gate on the squared distance (chi-square, 2 degrees of freedom)."""
        return gate_threshold(self.gate_probability, 2)

    def __post_init__(self) -> None:
        check_phd_settings(self)
        require(self.birth_velocity_sd_mps > 0 and math.isfinite(self.birth_velocity_sd_mps),
                f"birth_velocity_sd_mps must be positive, got {self.birth_velocity_sd_mps}")
        require(self.cluster_sd_m > 0 and math.isfinite(self.cluster_sd_m),
                f"cluster_sd_m must be positive, got {self.cluster_sd_m}")
        require(self.regularisation >= 0 and math.isfinite(self.regularisation),
                f"regularisation must be finite and >= 0, got {self.regularisation}")


def check_model(model: MeasurementModel, what: str = "the Cartesian SMC-PHD filter") -> None:
    """One-line refusal of a detection model whose detections fix no position (births need one)."""
    try:
        FixInitiator(min_pairs=1).check(model, what)
    except ConfigError:
        raise ConfigError(f"{what} births targets from position fixes of each detection's (bistatic range, "
                          f"azimuth) in 2-D; the detections measure {list(model.components)} in "
                          f"{model.geometry.dim}-D") from None


def check_detections(z: torch.Tensor, valid: torch.Tensor, model: MeasurementModel) -> None:
    """One-line errors for detections ``z (B, K, S, J, d)`` / ``valid (B, K, S, J)`` of ``model``
    the filter can not read."""
    S, d = model.n_pairs, len(model.components)
    if z.dim() != 5 or tuple(z.shape[2:3]) + tuple(z.shape[-1:]) != (S, d) or tuple(valid.shape) != tuple(z.shape[:-1]):
        raise ConfigError(f"detections must be z (runs, scans, {S} pairs, J, {d}) with valid (runs, scans, pairs, J), "
                          f"got {tuple(z.shape)} and {tuple(valid.shape)}")
    bad = valid & ~torch.isfinite(z).all(-1)
    if bool(bad.any()):
        b, k, s, j = (int(v) for v in bad.nonzero()[0])
        raise ConfigError(f"detection {j} of pair {s}, scan {k} (run {b}) is not finite (NaN or inf): the SMC-PHD "
                          "filter needs every component of every valid detection")


def psd_root(P: torch.Tensor) -> torch.Tensor:
    """A square root ``L (..., n, n)`` with ``L L^T = P`` of symmetric positive semi-definite ``P``
    (eigen-decomposition: a spread of copies of a few particles is singular, Cholesky would fail)."""
    lam, V = torch.linalg.eigh(0.5 * (P + P.transpose(-1, -2)))
    return V * lam.clamp(min=0).sqrt()[..., None, :]


class CartesianPHD:
    """The filter of the module docstring: ``motion`` with PSD ``q`` and scans ``dt`` s apart; detections
    of ``model`` (pair layout, ``S`` pairs) with detection probability ``pd`` and clutter intensity
    ``kappa (S,)`` per pair (per unit of the pair's measurement space, azimuth in rad); births'
    deviations ``other_sd (n,)`` for the entries neither the fix nor the rate sets. Its tensors are on
    ``other_sd``'s device (the detections' it reads).

    ``window_component``: the measurement component whose residual bounds the likelihood's windows
    (:meth:`weighted_likelihood`), the first that is not an angle (an angle's residual wraps, so it
    does not sort); None forms every particle-detection pair (the full product, the same numbers)."""

    def __init__(self, spec: CartesianPHDSpec, motion: KinematicModel, dt: float, q, model: MeasurementModel,
                 pd: float, kappa, other_sd: torch.Tensor):
        check_model(model)
        self.other_sd = torch.as_tensor(other_sd, dtype=torch.float64)
        dev = self.other_sd.device
        kappa = [float(k) for k in torch.as_tensor(kappa, dtype=torch.float64, device=dev).reshape(-1)]
        require(len(kappa) == model.n_pairs, f"need one clutter intensity per pair ({model.n_pairs}), got {len(kappa)}")
        require(0 < pd <= 1, f"pd must be in (0, 1], got {pd}")
        require(all(k >= 0 and math.isfinite(k) for k in kappa),
                f"clutter intensities must be finite and >= 0, got {kappa}")
        self.spec, self.motion, self.model = spec, motion, model
        self.pd, self.kappa = float(pd), kappa
        self.n = motion.dim_x
        self.F = motion.F(dt, device=dev)
        self.Q = motion.Q(dt, q, device=dev)
        self.L = motion.noise_factor(dt, q, device=dev)
        self.pairs = [model.for_pairs([s]) for s in range(model.n_pairs)]
        self.sd = torch.tensor(model.noise_std, dtype=torch.float64, device=dev)
        self.angle = [c == "azimuth" for c in model.components]
        self.window_component = next((c for c, a in enumerate(self.angle) if not a), None)
        self._log_norm = -0.5 * len(model.components) * math.log(2 * math.pi) - float(self.sd.log().sum())
        self.pos, self.vel = list(motion.pos_idx), list(motion.vel_idx)
        self.fix = FixInitiator(min_pairs=1)

    def empty(self, B: int) -> PHDState:
        zeros = lambda *shape: torch.zeros(shape, dtype=torch.float64, device=self.other_sd.device)
        return PHDState(zeros(B, 0, self.n), zeros(B, 0), zeros(B))

    def _move(self, x: torch.Tensor, g: torch.Generator) -> torch.Tensor:
        return x @ self.F.T + standard_normal(x.shape, g, device=x.device) @ self.L.T

    # -- 1. and 2.

    def predict(self, st: PHDState, g: torch.Generator) -> PHDState:
        """Survival and motion of the particles (step 1)."""
        ps = self.spec.survival
        return PHDState(self._move(st.x, g), st.w * ps, st.expected * ps)

    def births(self, z: torch.Tensor, valid: torch.Tensor, g: torch.Generator) -> PHDState:
        """Birth particles ``(B, S J particles_per_birth, n)`` seeded by the detections ``z (B, S, J, d)``,
        ``valid (B, S, J)`` of the previous scan and moved to this one (step 2); ``expected`` is the
        birth mass (``birth_rate`` where a run has a seed, else 0)."""
        B, S, J, d = z.shape
        nb, n = self.spec.particles_per_birth, self.n
        pos, cov, ok = self.fix.fixes(z, self.model, n)  # (B, S, J, 2), (B, S, J, 2, 2), (B, S, J)
        seed = valid & ok
        cov = torch.where(seed[..., None, None], cov, torch.eye(2, dtype=z.dtype, device=z.device))
        x0 = z.new_zeros(B, S, J, n)
        x0[..., self.pos] = pos
        # velocity: the prior N(0, sd^2 I) times the detection's rate row (linear in velocity at a known position)
        D = len(self.vel)
        prec = torch.eye(D, dtype=z.dtype, device=z.device).expand(B, S, J, D, D) / self.spec.birth_velocity_sd_mps**2
        eta = z.new_zeros(B, S, J, D)
        c = rate_component(self.model)
        if c is not None:
            var = self.model.noise_std[c] ** 2
            grad = torch.stack([self.pairs[s].jacobian(x0[:, s])[..., c, :][..., self.vel] for s in range(S)], 1)
            prec = prec + grad[..., :, None] * grad[..., None, :] / var
            eta = grad * (z[..., c] / var)[..., None]
        Pv = torch.linalg.inv(prec)
        x0[..., self.vel] = (Pv @ eta[..., None])[..., 0]
        eps = standard_normal((B, S, J, nb, n), g, device=z.device)
        xb = x0[:, :, :, None, :] + eps * self.other_sd
        for idx, root in ((self.pos, psd_root(cov)), (self.vel, psd_root(Pv))):
            xb[..., idx] = x0[..., idx][..., None, :] + eps[..., idx] @ root.transpose(-1, -2)
        xb = self._move(xb.reshape(B, S * J * nb, n), g)
        count = seed.sum((1, 2))  # (B,)
        share = torch.where(count > 0, self.spec.birth_rate / (count.clamp(min=1) * nb), z.new_zeros(()))
        wb = seed[..., None].expand(B, S, J, nb).reshape(B, S * J * nb).to(z.dtype) * share[:, None]
        mass = torch.where(count > 0, z.new_full((), self.spec.birth_rate), z.new_zeros(()))
        return PHDState(xb, wb, mass)

    # -- 3.

    def weighted_likelihood(self, st: PHDState, s: int, z: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """``Pd g_ij w_i (B, M, J)`` of pair ``s``'s detections ``z (B, J, d)`` (0 for padding on either
        side), formed in the exponent: ``e_ij = log(Pd w_i) + log N(z_j; h_s(x_i), R)``, and 0 where
        ``e_ij < -700`` (:meth:`_exponent`).

        Only the pairs that can pass that cut are formed (:meth:`_windows`): ``e_ij`` is at most
        ``log(Pd w_i) + log c - r_ij^2 / (2 sd^2)`` in any one non-angle component (range: ``r`` its
        residual), so a detection farther than ``sd sqrt(2 (700 + log(Pd c w_i)))`` from particle
        ``i``'s predicted value in that component is a 0 of the full product. The detections are
        sorted in it and each particle reads the run of them inside its window: the same values as
        the full ``(B, M, J)`` product, from a few columns per particle instead of ``J``."""
        hx = self.pairs[s].h(st.x)  # (B, M, d)
        row = torch.log(self.pd * st.w) + self._log_norm  # (B, M), -inf for padding
        B, M, J = hx.shape[0], hx.shape[1], z.shape[1]
        if self.window_component is None or M == 0 or J == 0:
            col = torch.where(valid, z.new_zeros(()), z.new_full((), -math.inf))
            e = self._exponent(z[:, None, :, :], hx[:, :, None, :], row[:, :, None]).add_(col[:, None, :])
            return e.masked_fill_(e < -700.0, -math.inf).exp_()
        particle, detection = self._windows(hx, row, z, valid)  # (P,) each: the pairs inside the windows
        e = self._exponent(z.reshape(B * J, -1).index_select(0, detection), hx.reshape(B * M, -1).index_select(
            0, particle), row.reshape(-1).index_select(0, particle))
        out = e.new_zeros(B * M * J)
        # particle = b M + i and detection = b J + j, so entry (b, i, j) of the flat output is particle J + j;
        # an exponent below -700 is 0: exp there is subnormal, ~10x slower on x86, and (< 1e-304) changes no sum
        out.index_copy_(0, particle * J + detection.remainder(J), e.masked_fill_(e < -700.0, -math.inf).exp_())
        return out.reshape(B, M, J)

    def _exponent(self, z: torch.Tensor, hx: torch.Tensor, row: torch.Tensor) -> torch.Tensor:
        """``row - sum_c (wrapped z_c - hx_c)^2 / (2 sd_c^2)`` broadcast over ``z (..., d)`` and ``hx (..., d)``
        (each component's square summed in order, so a pair's exponent is the same number whichever
        layout holds it)."""
        e = None
        for c in range(len(self.angle)):
            r = z[..., c] - hx[..., c]
            if self.angle[c]:
                r = wrap_angle(r)
            r = r.mul_(1.0 / float(self.sd[c])).square_()
            e = r if e is None else e.add_(r)
        return e.mul_(-0.5).add_(row)

    def _windows(self, hx: torch.Tensor, row: torch.Tensor, z: torch.Tensor, valid: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor]:
        """The (particle, detection) pairs inside the particles' windows (:meth:`weighted_likelihood`)
        of predicted values ``hx (B, M, d)``, log-weights ``row (B, M)`` and detections ``z (B, J, d)``,
        ``valid (B, J)``: flat indices ``(P,)``, ``b M + i`` and ``b J + j``, grouped by particle."""
        B, M, J = hx.shape[0], hx.shape[1], z.shape[1]
        c = self.window_component
        # the half-width where the exponent's bound reaches -700, widened by 1e-9 so rounding keeps every
        # pair the full product keeps; a padding particle (row -inf) gets width 0
        half = float(self.sd[c]) * torch.sqrt(2.0 * (700.0 + row).clamp(min=0.0)) * (1.0 + 1e-9)  # (B, M)
        key, order = torch.where(valid, z[..., c], z.new_full((), math.inf)).sort(1)  # (B, J)
        h = hx[..., c]
        # both ends by one search; a detection exactly at the (widened) upper end is past the cut either way
        ends = torch.searchsorted(key, torch.cat([h - half, h + half], 1))  # (B, 2 M)
        lo = ends[:, :M].reshape(-1)
        count = ends[:, M:].reshape(-1) - lo
        dev = hx.device
        particle = torch.repeat_interleave(torch.arange(B * M, device=dev), count)  # (P,): b M + i
        start = torch.repeat_interleave(count.cumsum(0) - count, count)
        b = particle.div(M, rounding_mode="floor")
        # b J + j, in each run's sorted order
        flat_order = (order + (torch.arange(B, device=dev) * J)[:, None]).reshape(-1)
        return particle, flat_order.index_select(0, b * J + lo.index_select(0, particle)
                                                 + torch.arange(len(particle), device=dev) - start)

    def update(self, st: PHDState, s: int, z: torch.Tensor, valid: torch.Tensor):
        """Pair ``s``'s PHD update with its detections ``z (B, J, d)``: the state and the detections'
        partitions (:func:`~.phd.correct`): their weighted means ``part_x (B, J, n)``, masses
        ``part_w (B, J)`` and position spreads ``part_P (B, J, 2, 2)``."""
        pg = self.weighted_likelihood(st, s, z, valid)
        new, part_x, part_w = correct(st, pg, valid, self.pd, self.kappa[s])
        p = st.x[..., self.pos]
        second = torch.bmm(pg.transpose(1, 2), torch.stack([p[..., 0] ** 2, p[..., 0] * p[..., 1], p[..., 1] ** 2], -1))
        second = second / pg.sum(1).clamp(min=1e-300)[..., None]  # (B, J, 3): E[x^2], E[xy], E[y^2]
        m = part_x[..., self.pos]
        cxx, cxy, cyy = (second[..., 0] - m[..., 0] ** 2, second[..., 1] - m[..., 0] * m[..., 1],
                         second[..., 2] - m[..., 1] ** 2)
        part_P = torch.stack([torch.stack([cxx, cxy], -1), torch.stack([cxy, cyy], -1)], -2)
        return new, part_x, part_w, part_P

    # -- 4. and 5.

    def _spread(self, P: torch.Tensor) -> torch.Tensor:
        """Spreads ``P (..., 2, 2)`` symmetrised and floored by ``cluster_sd_m^2`` per axis: a clustering metric's covariance."""
        eye = torch.eye(2, dtype=P.dtype, device=P.device)
        return 0.5 * (P + P.transpose(-1, -2)) + self.spec.cluster_sd_m**2 * eye

    def estimate(self, st: PHDState, seeds: torch.Tensor, seed_mass: torch.Tensor, seed_P: torch.Tensor):
        """Clusters (step 4) from the partitions ``seeds (B, S, n)``, ``seed_mass (B, S)``, ``seed_P
        (B, S, 2, 2)``: ``(x (B, C, n), P (B, C, n, n), mass (B, C), exists (B, C), owner (B, M))``.

        The metric of a centre is its seed's position spread plus ``cluster_sd_m^2`` per axis: a
        newborn's cloud (the fixes' cross-range deviation is the azimuth's, hundreds of metres)
        is one cluster, not several, while a target followed for a while gates at a few of its
        deviations. Two seeds are one target when inside the gate of the sum of their spreads."""
        B, S = seed_mass.shape
        sp = seeds[..., self.pos]
        W = whitening(self._spread(seed_P))  # (B, S, 2, 2)
        pair_S = self._spread(seed_P[:, :, None] + seed_P[:, None, :] + self.spec.cluster_sd_m**2 * torch.eye(
            2, dtype=seed_P.dtype, device=seed_P.device))  # (B, S, S, 2, 2)
        near_seeds = inside_gate(mahalanobis(sp[:, :, None] - sp[:, None, :], pair_S), self.spec.gate)

        def d2(x, c, which):
            Wc = W.gather(1, which[..., None, None].expand(*which.shape, 2, 2))  # (B, C, 2, 2)
            return whitened_d2(x[..., self.pos][:, :, None] - c[..., self.pos][:, None], Wc[:, None])

        # keep 0: a cluster a partition of at least estimate_mass seeded is an estimate whatever its final
        # mass; the iterated corrector leaves a target the last pair missed with 1 - Pd of its mass
        return cluster(st, seeds, seed_mass, d2, self.spec.gate, self.spec.estimate_mass, self.spec.kmeans_iterations,
                       keep=0.0, near_seeds=near_seeds)

    def resample(self, st: PHDState, owner: torch.Tensor, P: torch.Tensor, g: torch.Generator) -> PHDState:
        """Resampling and regularisation (step 5) of particles whose clusters are ``owner (B, M)``
        (``C``: none) with spreads ``P (B, C, n, n)``."""
        B, M = st.w.shape
        C, n = P.shape[1], self.n
        if M == 0:
            return st
        spec = self.spec
        comp = torch.where(st.w > 0, owner, torch.full_like(owner, C + 1))  # C: no cluster; C + 1: padding
        mass = st.w.new_zeros(B, C + 2).scatter_add_(1, comp, st.w)[:, :C + 1]  # (B, C + 1)
        per_mass = torch.round(spec.particles_per_target * mass)
        counts = torch.cat([per_mass[:, :C].clamp(min=spec.particles_per_target),
                            per_mass[:, C:].clamp(min=spec.particles_per_birth)], 1)
        counts = torch.where(mass > 0, counts, torch.zeros_like(counts)).to(torch.int64)
        share = torch.cat([mass, mass.new_ones(B, 1)], 1).gather(1, comp)
        logw = torch.log(st.w / share.clamp(min=1e-300))
        x, own, logw = segmented_resample(st.x, logw, comp, mass > 0, counts, g)
        w = torch.where(own <= C, logw.exp() * torch.cat([mass, mass.new_zeros(B, 1)], 1).gather(1, own),
                        st.w.new_zeros(()))
        if spec.regularisation == 0 or C == 0 or x.shape[1] == 0:
            return PHDState(x, w, st.expected)
        A = (4.0 / (n + 2)) ** (1.0 / (n + 4))
        h = spec.regularisation * A * counts[:, :C].clamp(min=1).to(x.dtype) ** (-1.0 / (n + 4))  # (B, C)
        root = psd_root(P) * h[..., None, None]  # (B, C, n, n)
        eps = standard_normal(x.shape, g, device=x.device)
        for c in range(C):  # few clusters: one batched product each
            x = torch.where((own == c)[..., None], x + eps @ root[:, c].transpose(1, 2), x)
        return PHDState(x, w, st.expected)

    def run(self, z: torch.Tensor, valid: torch.Tensor, g: torch.Generator) -> PHDEstimates:
        """The filter over detections ``z (B, K, S, J, d)`` / ``valid (B, K, S, J)`` (NaN where padded):
        per scan the estimates ``x (B, K, C, n)``, ``P (B, K, C, n, n)``, ``mass``, ``exists``, the
        PHD's integral after the update ``expected (B, K)`` and the particles after resampling."""
        check_detections(z, valid, self.model)
        B, K, S = valid.shape[:3]
        z = torch.nan_to_num(z.to(torch.float64))
        # each scan keeps only the columns some run and pair fills (valid detections come first in a list)
        width = [int(valid[:, k].sum(-1).max()) if valid.shape[-1] else 0 for k in range(K)]
        st = self.empty(B)
        out = {k: [] for k in ("x", "P", "mass", "exists", "expected", "particles")}
        for k in range(K):
            st = self.predict(st, g)
            if k and width[k - 1]:
                born = self.births(z[:, k - 1, :, :width[k - 1]], valid[:, k - 1, :, :width[k - 1]], g)
                st = PHDState(torch.cat([st.x, born.x], 1), torch.cat([st.w, born.w], 1), st.expected + born.expected)
            parts = []
            for s in range(S):
                st, *part = self.update(st, s, z[:, k, s, :width[k]], valid[:, k, s, :width[k]])
                parts.append(part)
            xe, Pe, me, ee, owner = self.estimate(st, *(torch.cat(v, 1) for v in zip(*parts)))
            out["expected"].append(st.expected)
            st = self.resample(st, owner, Pe, g)
            out["particles"].append((st.w > 0).sum(1))
            for name, v in (("x", xe), ("P", Pe), ("mass", me), ("exists", ee)):
                out[name].append(v)
        C = max((v.shape[1] for v in out["x"]), default=0)
        pad = lambda vs, fill: torch.stack([torch.nn.functional.pad(v, (0, 0) * (v.dim() - 2) + (0, C - v.shape[1]),
                                                                    value=fill) for v in vs], 1)
        return PHDEstimates(pad(out["x"], float("nan")), pad(out["P"], 0.0), pad(out["mass"], 0.0),
                            pad(out["exists"], False), torch.stack(out["expected"], 1),
                            torch.stack(out["particles"], 1))
