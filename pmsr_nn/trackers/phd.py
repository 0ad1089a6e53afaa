"""SMC-PHD filter (Vo, Singh & Doucet 2005) in the bistatic plane, batched over runs x particles.

A target's state is ``[r, rdot]``: bistatic range (m) and bistatic range-rate (m/s), constant
velocity with the discrete white-acceleration noise of the Daniyan seed (Eq. 3, ``sigma`` in
m/s^2), measured directly (Eq. 4, ``H = I``, ``R = diag(sd^2)``). The PHD is a weighted particle
set whose weights sum to the expected number of targets. One scan:

1. **predict**: every particle moves with the CV model plus drawn process noise; weights x ``p_S``;
2. **birth** (measurement-driven, after Ristic, Clark, Vo & Vo 2012, "Adaptive target birth
   intensity for PHD and CPHD filters"): particles are drawn around detections of the *previous*
   scan (``N(z, R)``) and moved one step, so no birth is placed where nothing was seen. With
   ``adaptive_birth`` (the default) a detection ``j`` seeds a birth in proportion to how little the
   persistent PHD (the particles not born this scan) explained it in its update: ``u_j = 1 - s_j``,
   ``s_j = sum_{i persistent} Pd g_ij w_i / (kappa + sum_l Pd g_lj w_l)``. Its birth mass is
   ``birth_rate u_j / max(1, U)`` (``U = sum_j u_j``: the prior's ``birth_rate`` expected newborn
   targets per scan shared among the unexplained detections) and its particle count follows that
   mass: ``round(u_j max(birth_particles_min, particles_per_birth / max(1, U)))``, i.e.
   ``particles_per_birth`` particles for a scan's whole birth mass, at least ``birth_particles_min``
   per unexplained detection (a birth needs enough particles to represent ``N(z, R)`` should it be
   a target). A detection an existing target explains (``u_j`` near 0) seeds no particle and no
   mass, and clutter births cost ``birth_particles_min`` each instead of ``particles_per_birth``.
   Without ``adaptive_birth``: ``particles_per_birth`` particles on every detection, the mass
   ``birth_rate`` shared equally among them (the filter before issue 37);
3. **update** with the current detections (Pd, clutter intensity ``kappa`` per m x m/s):
   ``w_i <- (1 - Pd) w_i + sum_j Pd g_ij w_i / (kappa + sum_l Pd g_lj w_l)``; also each
   detection's share ``s_j`` taken by the persistent particles (the next scan's births read it);
4. **estimates** by a gated weighted k-means of the particles: the seeds are the per-detection
   partitions of the PHD (the mass and mean each detection takes in step 3, as Ristic et al.'s
   extraction), picked greedily by mass, heaviest first, skipping seeds inside a picked one's gate,
   while the mass is at least ``estimate_mass``; Lloyd iterations refine them, each particle
   joining its nearest centre when inside the gate (far particles, e.g. births on clutter, are
   left out of every centre so they do not pull it); a cluster of at least ``estimate_mass`` is an
   estimate. The count is therefore decided per cluster, not as ``round(sum w)``: with ``Pd < 1``
   a detected target's PHD mass settles at ``1 / Pd`` (the missed-detection term keeps ``1 - Pd``
   of it; 1.11 at Pd 0.9), so rounding the total counts a phantom target every few detected ones,
   while a missed target's mass (``1 - Pd`` of it) gives no estimate and its track coasts;
5. **resample** (systematic, per run) to ``particles_per_target x expected number`` particles
   (at least ``particles_per_birth``), each weighing ``expected / count``: the mass is kept.

Runs are the batch dimension; each run's particle count adapts, the runs are padded to the
largest (weight 0). The expected number is also carried analytically (:attr:`PHDState.expected`)
so a test can hold the particle weights to it after every step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.particle import segmented_resample
from ..rng import standard_normal
from .gating import gate_threshold, inside_gate, pairwise_d2

@dataclass(frozen=True)
class PHDSpec:
    """Settings of the SMC-PHD filter (module docstring). Deviations in the state's units (m, m/s)."""

    particles_per_target: int = 4000
    particles_per_birth: int = 800
    survival: float = 0.99
    birth_rate: float = 0.05
    process_sd_mps2: float = 20.0
    kmeans_iterations: int = 1
    estimate_mass: float = 0.5
    gate_probability: float = 0.999
    adaptive_birth: bool = True
    birth_particles_min: int = 100

    @property
    def gate(self) -> float:
        """The gate on the squared Mahalanobis distance (chi-square, 2 degrees of freedom)."""
        return gate_threshold(self.gate_probability, 2)

    def __post_init__(self) -> None:
        check_phd_settings(self)
        require(self.process_sd_mps2 >= 0 and math.isfinite(self.process_sd_mps2),
                f"process_sd_mps2 must be finite and >= 0, got {self.process_sd_mps2}")
        require(isinstance(self.adaptive_birth, bool), f"adaptive_birth must be true or false, got {self.adaptive_birth!r}")
        require(self.birth_particles_min >= 10,
                f"birth_particles_min must be at least 10 (particles per unexplained detection), got {self.birth_particles_min}")


def check_phd_settings(spec) -> None:
    """The checks every SMC-PHD's settings share (this module's and
    :mod:`.phd_cartesian`'s): particle counts, birth mass, survival, estimate mass, clustering."""
    require(spec.particles_per_target >= 10 and spec.particles_per_birth >= 10,
            f"particles per target and per birth must be at least 10, got {spec.particles_per_target} and "
            f"{spec.particles_per_birth}")
    require(spec.birth_rate > 0 and math.isfinite(spec.birth_rate),
            f"the birth intensity has no mass: birth_rate must be positive (expected newborn targets per scan), "
            f"got {spec.birth_rate}")
    require(0 < spec.survival <= 1, f"survival must be in (0, 1], got {spec.survival}")
    require(0 < spec.estimate_mass <= 1, f"estimate_mass must be in (0, 1], got {spec.estimate_mass}")
    require(spec.kmeans_iterations >= 0, f"kmeans_iterations must be >= 0, got {spec.kmeans_iterations}")
    require(0 < spec.gate_probability < 1, f"gate_probability must be in (0, 1), got {spec.gate_probability}")


def cv_matrices(dt: float, sigma: float, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """``F (2, 2)`` and ``Q (2, 2)`` of the seed's Eq. 3: ``Q = sigma^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]``
    (on ``device``)."""
    F = torch.tensor([[1.0, dt], [0.0, 1.0]], dtype=torch.float64, device=device)
    Q = sigma**2 * torch.tensor([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]], dtype=torch.float64, device=device)
    return F, Q


@dataclass
class PHDState:
    """Particles ``x (B, M, 2)``, weights ``w (B, M)`` (0: padding), ``expected (B,)`` the PHD's
    expected number of targets carried by the recursion's formulas (equal to ``w.sum(1)``).
    After a prediction, ``persistent``: the leading particles that were not born this scan (the
    births follow them); after an update, ``explained (B, J)``: the share of each of that scan's
    detections the persistent particles took (``s_j``; the adaptive births of the next scan read
    it). Both null where unknown (a filter that does not track them)."""

    x: torch.Tensor
    w: torch.Tensor
    expected: torch.Tensor
    persistent: int | None = None
    explained: torch.Tensor | None = None


@dataclass
class PHDEstimates:
    """Per scan: ``x (B, K, C, 2)``, ``P (B, K, C, 2, 2)`` the weighted spread of the particles
    of each estimate, ``mass (B, K, C)``, ``exists (B, K, C)``; ``expected (B, K)`` the PHD's
    integral after the update; ``particles (B, K)`` the particle count after resampling."""

    x: torch.Tensor
    P: torch.Tensor
    mass: torch.Tensor
    exists: torch.Tensor
    expected: torch.Tensor
    particles: torch.Tensor


def check_detections(z: torch.Tensor, valid: torch.Tensor) -> None:
    """One-line errors for detections ``z (B, K, J, 2)`` / ``valid (B, K, J)`` a filter can not read."""
    if z.dim() != 4 or z.shape[-1] != 2 or tuple(valid.shape) != tuple(z.shape[:-1]):
        raise ConfigError(f"detections must be z (runs, scans, J, 2) with valid (runs, scans, J), got "
                          f"{tuple(z.shape)} and {tuple(valid.shape)}")
    bad = valid & ~torch.isfinite(z).all(-1)
    if bool(bad.any()):
        b, k, j = (int(v) for v in bad.nonzero()[0])
        raise ConfigError(f"detection {j} of scan {k} (run {b}) is not finite (NaN or inf): the SMC-PHD filter needs "
                          "finite range and range-rate for every valid detection")


def correct(st: PHDState, pg: torch.Tensor, valid: torch.Tensor, pd: float, kappa: float
            ) -> tuple[PHDState, torch.Tensor, torch.Tensor]:
    """The PHD update (step 3 of the module docstring) of particles ``st`` given ``pg (B, M, J)``, the
    weighted likelihoods ``Pd g_ij w_i`` of detections ``valid (B, J)``, and the clutter intensity
    ``kappa`` (per unit of the measurement space, as ``g``): the updated state, and each detection's
    partition, the mass it takes ``part_w (B, J)`` (negative where ``j`` is padding) and its weighted
    mean ``part_x (B, J, n)``. Where ``st.persistent`` is known, the state carries ``explained (B, J)``,
    the share of each detection the leading ``st.persistent`` particles took (0 for padding)."""
    P = st.persistent
    taken_p = None if P is None else pg[:, :P].sum(1)  # (B, J): the persistent particles' part
    taken = pg.sum(1) if P is None else taken_p + pg[:, P:].sum(1)  # (B, J)
    denom = kappa + taken
    inv = torch.where(denom > 0, 1.0 / denom, denom.new_zeros(()))
    part_w = taken * inv
    # sum_j Pd g_ij w_i / denom_j as one product (no (B, M, J) ratio tensor)
    w = (1 - pd) * st.w + torch.bmm(pg, inv[:, :, None])[..., 0]
    part_x = torch.bmm(pg.transpose(1, 2), st.x) / taken.clamp(min=1e-300)[..., None]
    expected = (1 - pd) * st.expected + part_w.sum(1)
    explained = None if P is None else torch.where(valid, taken_p * inv, w.new_zeros(()))
    part_w = torch.where(valid & (taken > 0), part_w, w.new_full((), -1.0))
    return PHDState(st.x, w, expected, explained=explained), part_x, part_w


def cluster(st: PHDState, seeds: torch.Tensor, seed_mass: torch.Tensor, d2, gate: float, least: float,
            iterations: int, keep: float | None = None, near_seeds: torch.Tensor | None = None):
    """Gated weighted k-means of the particles ``st.x (B, M, n)`` (weights ``st.w``) from candidate
    centres ``seeds (B, S, n)`` ranked by ``seed_mass (B, S)`` (negative: not a candidate), in the
    metric ``d2(points (B, P, n), centres (B, C, n), which (B, C)) -> (B, P, C)`` (squared, gated at
    ``gate``; ``which``: the seed each centre came from, for a metric per seed): greedily the
    heaviest seed of mass at least ``least``, dropping the seeds inside its gate (``near_seeds (B, S,
    S)``, null: row ``i`` of ``d2(seeds, seeds)`` inside the gate); then ``iterations`` Lloyd passes, each
    particle joining its nearest centre when inside the gate.
    Returns ``x (B, C, n)`` (the weighted means), ``P (B, C, n, n)`` (the weighted spreads),
    ``mass (B, C)``, ``exists (B, C)`` (a positive mass of at least ``keep``, null: ``least``) and
    ``owner (B, M)`` (each particle's cluster, ``C``: none)."""
    B, M = st.w.shape
    n = st.x.shape[-1]
    S = seeds.shape[1]
    dev = st.x.device
    if near_seeds is None:
        near_seeds = inside_gate(d2(seeds, seeds, torch.arange(S, device=dev).expand(B, S)), gate)  # (B, S, S)
    centres, exists, picked = [], [], []
    for _ in range(S):  # greedy: the heaviest seed, then drop the seeds inside its gate
        best = seed_mass.argmax(1)
        ok = seed_mass.gather(1, best[:, None])[:, 0] >= least
        if not bool(ok.any()):
            break
        centres.append(seeds.gather(1, best[:, None, None].expand(B, 1, n))[:, 0])
        exists.append(ok)
        picked.append(best)
        near = near_seeds.gather(1, best[:, None, None].expand(B, 1, S))[:, 0]
        seed_mass = torch.where(near & ok[:, None], torch.full((), -1.0, dtype=torch.float64, device=dev), seed_mass)
    C = len(centres)
    if C == 0:
        zeros = lambda *shape, dtype=torch.float64: torch.zeros(shape, dtype=dtype, device=dev)
        return (zeros(B, 0, n), zeros(B, 0, n, n), zeros(B, 0), zeros(B, 0, dtype=torch.bool),
                zeros(B, M, dtype=torch.int64))
    # (B, C, n), (B, C), (B, C)
    centre, exists, which = torch.stack(centres, 1), torch.stack(exists, 1), torch.stack(picked, 1)
    base = (torch.arange(B, device=dev) * (C + 1))[:, None]
    w = st.w.reshape(-1)
    binned = lambda owner, v: torch.bincount(owner, v, minlength=B * (C + 1)).reshape(B, C + 1)[:, :C]
    for it in range(iterations + 1):  # the last pass only assigns (and gives P)
        dist = d2(st.x, centre, which).masked_fill_(~exists[:, None, :], math.inf)
        near_d2, owner = dist.min(2)
        owner = (torch.where(inside_gate(near_d2, gate), owner, torch.full_like(owner, C)) + base).reshape(-1)  # C: no gate
        mass = binned(owner, w)
        if it == iterations:
            break
        mean = torch.stack([binned(owner, w * st.x[..., d].reshape(-1)) for d in range(n)], -1)
        centre = torch.where((mass > 0)[..., None], mean / mass.clamp(min=1e-300)[..., None], centre)
    padded = torch.cat([centre, centre.new_zeros(B, 1, n)], 1).reshape(-1, n)
    dev = st.x.reshape(-1, n) - padded[owner]
    P = centre.new_zeros(B, C, n, n)
    for i in range(n):
        for j in range(i, n):
            P[..., i, j] = P[..., j, i] = binned(owner, w * dev[:, i] * dev[:, j])
    P = P / mass.clamp(min=1e-300)[..., None, None]
    keep = least if keep is None else keep
    return centre, P, mass, exists & (mass >= keep) & (mass > 0), owner.reshape(B, M) - base


class SMCPHD:
    """The filter of the module docstring for detections with deviations ``sd (2,)`` (m, m/s),
    detection probability ``pd`` and clutter intensity ``kappa`` (per scan, per m x m/s), scans
    ``dt`` s apart; its tensors are on ``sd``'s device (the detections' it reads)."""

    def __init__(self, spec: PHDSpec, sd: torch.Tensor, pd: float, kappa: float, dt: float):
        require(0 < pd <= 1, f"pd must be in (0, 1], got {pd}")
        require(kappa >= 0 and math.isfinite(kappa), f"the clutter intensity must be finite and >= 0, got {kappa}")
        self.spec, self.pd, self.kappa, self.gate = spec, float(pd), float(kappa), spec.gate
        self.sd = torch.as_tensor(sd, dtype=torch.float64)
        dev = self.sd.device
        self.F, self.Q = cv_matrices(dt, spec.process_sd_mps2, dev)
        # Q = G G^T has rank one: the noise is one white acceleration per step, a ~ N(0, sigma^2), moving x by G a
        self.G = spec.process_sd_mps2 * torch.tensor([dt**2 / 2, dt], dtype=torch.float64, device=dev)
        self._norm = 1.0 / (2 * math.pi * float(self.sd.prod()))

    def empty(self, B: int) -> PHDState:
        zeros = lambda *shape: torch.zeros(shape, dtype=torch.float64, device=self.sd.device)
        return PHDState(zeros(B, 0, 2), zeros(B, 0), zeros(B))

    def _move(self, x: torch.Tensor, g: torch.Generator) -> torch.Tensor:
        return x @ self.F.T + standard_normal(x.shape[:-1] + (1,), g, device=x.device) * self.G

    def predict(self, st: PHDState, z_prev: torch.Tensor | None, valid_prev: torch.Tensor | None,
                g: torch.Generator) -> PHDState:
        """Survival and motion of the particles, then the births around ``z_prev (B, J, 2)`` (with
        ``adaptive_birth``, weighted by ``st.explained``, the update's shares of those detections:
        null counts them unexplained). The result's ``persistent``: the particles before the births."""
        ps = self.spec.survival
        x, w = self._move(st.x, g), st.w * ps
        expected = st.expected * ps
        persistent = x.shape[1]
        if z_prev is not None and z_prev.shape[1] and self.spec.adaptive_birth:
            xb, wb, mass = self.births(z_prev, valid_prev, st.explained, g)
            x, w, expected = torch.cat([x, xb], 1), torch.cat([w, wb], 1), expected + mass
        elif z_prev is not None and z_prev.shape[1]:
            B, J, _ = z_prev.shape
            n = self.spec.particles_per_birth
            seeds = torch.where(valid_prev[..., None], z_prev, z_prev.new_zeros(()))
            xb = seeds[:, :, None, :] + standard_normal((B, J, n, 2), g, device=z_prev.device) * self.sd
            xb = self._move(xb.reshape(B, J * n, 2), g)
            count = valid_prev.sum(1)  # (B,)
            share = torch.where(count > 0, self.spec.birth_rate / (count.clamp(min=1) * n),
                                torch.zeros((), device=count.device))
            wb = (valid_prev[:, :, None].expand(B, J, n).reshape(B, J * n)).to(torch.float64) * share[:, None]
            x, w = torch.cat([x, xb], 1), torch.cat([w, wb], 1)
            expected = expected + torch.where(count > 0, torch.full_like(expected, self.spec.birth_rate),
                                              torch.zeros_like(expected))
        return PHDState(x, w, expected, persistent=persistent)

    def births(self, z: torch.Tensor, valid: torch.Tensor, explained: torch.Tensor | None, g: torch.Generator
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The adaptive births (module docstring, step 2) around detections ``z (B, J, 2)`` / ``valid (B, J)``
        whose shares taken by the persistent PHD were ``explained (B, J)`` (null: none): particles
        ``x (B, N, 2)`` (moved one step; padding weighs 0), weights ``w (B, N)`` and each run's birth
        mass ``(B,)``. A birth given no particle is given no mass, so the mass stays ``w.sum(1)``."""
        spec = self.spec
        B, J, _ = z.shape
        dev = z.device
        s = torch.zeros(B, J, dtype=torch.float64, device=dev) if explained is None else explained.to(torch.float64)
        u = torch.where(valid, (1.0 - s).clamp(0.0, 1.0), torch.zeros((), dtype=torch.float64, device=dev))  # (B, J)
        U = u.sum(1, keepdim=True).clamp(min=1.0)  # (B, 1)
        per = torch.clamp(spec.particles_per_birth / U, min=float(spec.birth_particles_min))
        n = torch.round(u * per).to(torch.int64)  # (B, J): particles follow the mass, floored per birth
        mass = torch.where(n > 0, spec.birth_rate * u / U, torch.zeros((), dtype=torch.float64, device=dev))  # (B, J)
        ends = n.cumsum(1)
        total = ends[:, -1]
        N = int(total.max())
        pos = torch.arange(N, device=dev).expand(B, N)
        seed = torch.searchsorted(ends, pos.contiguous(), right=True).clamp(max=J - 1)  # (B, N): its detection
        born = pos < total[:, None]
        xb = z.gather(1, seed[..., None].expand(B, N, 2)) + standard_normal((B, N, 2), g, device=dev) * self.sd
        wb = torch.where(born, (mass / n.clamp(min=1)).gather(1, seed), mass.new_zeros(()))
        return self._move(xb, g), wb, mass.sum(1)

    def weighted_likelihood(self, st: PHDState, z: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """``Pd g_ij w_i (B, M, J)``: ``g_ij`` the Gaussian density of detection ``j`` given particle
        ``i`` (0 for padding on either side). Computed in the exponent, ``-d2 / 2 + log(Pd c w_i)``, with
        ``d2 = |x|^2 + |z|^2 - 2 x.z`` in units of the deviations: one batched product, no other
        ``(B, M, J)`` temporaries; the cancellation costs ``|x / sd|^2 x eps`` (below 1e-9 at 100 km)."""
        xs, zs = st.x / self.sd, z / self.sd
        row = torch.log(self.pd * self._norm * st.w) - 0.5 * (xs * xs).sum(-1)  # (B, M), -inf for padding
        col = torch.where(valid, -0.5 * (zs * zs).sum(-1), zs.new_full((), -math.inf))  # (B, J)
        e = torch.baddbmm(row[:, :, None] + col[:, None, :], xs, zs.transpose(1, 2))
        # exp below -708 is subnormal, which x86 handles ~10x slower; such a term (< 1e-304) changes no sum
        return e.masked_fill_(e < -700.0, -math.inf).exp_()

    def update(self, st: PHDState, z: torch.Tensor, valid: torch.Tensor) -> tuple[PHDState, torch.Tensor, torch.Tensor]:
        """The PHD update with detections ``z (B, J, 2)``; also each detection's partition: the mass it
        takes ``part_w (B, J)`` (negative where ``j`` is padding) and its weighted mean ``part_x (B, J, 2)``."""
        return correct(st, self.weighted_likelihood(st, z, valid), valid, self.pd, self.kappa)

    def _d2(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        """Squared Mahalanobis distances ``(B, M, C)`` between points ``x (B, M, 2)`` and ``c (B, C, 2)``
        under the detections' covariance ``diag(sd^2)`` (:func:`~.gating.pairwise_d2` of the points in
        units of the deviations)."""
        return pairwise_d2(x / self.sd, c / self.sd)

    def estimate(self, st: PHDState, seeds: torch.Tensor, seed_mass: torch.Tensor):
        """Gated weighted k-means (module docstring, :func:`cluster`) from candidate centres ``seeds (B, S, 2)``
        ranked by ``seed_mass (B, S)`` (the mass of each detection's partition; negative: not a candidate):
        ``(x (B, C, 2), P (B, C, 2, 2), mass (B, C), exists (B, C))``."""
        return cluster(st, seeds, seed_mass, lambda x, c, which: self._d2(x, c), self.gate, self.spec.estimate_mass,
                       self.spec.kmeans_iterations)[:4]

    def resample(self, st: PHDState, g: torch.Generator) -> PHDState:
        """Systematic resampling to the particle budget of the expected number (module docstring)."""
        B, M = st.w.shape
        mass = st.w.sum(1)
        spec = self.spec
        counts = torch.clamp(torch.round(st.expected * spec.particles_per_target), min=spec.particles_per_birth)
        counts = torch.where(mass > 0, counts, torch.zeros_like(counts)).to(torch.int64)[:, None]
        if M == 0:
            return st
        logw = torch.log(st.w / torch.where(mass > 0, mass, torch.ones_like(mass))[:, None])
        comp = torch.where(st.w > 0, 0, 1)
        x, comp_new, logw_new = segmented_resample(st.x, logw, comp, (mass > 0)[:, None], counts, g)
        w = torch.where(comp_new == 0, logw_new.exp() * mass[:, None], logw_new.new_zeros(()))
        return PHDState(x, w, st.expected, explained=st.explained)

    def run(self, z: torch.Tensor, valid: torch.Tensor, g: torch.Generator, progress=None) -> PHDEstimates:
        """The filter over detections ``z (B, K, J, 2)`` / ``valid (B, K, J)`` (NaN where padded)."""
        check_detections(z, valid)
        B, K = valid.shape[:2]
        z = torch.nan_to_num(z.to(torch.float64))
        st = self.empty(B)
        out = {k: [] for k in ("x", "P", "mass", "exists", "expected", "particles")}
        # each scan keeps only the columns some run fills: a list is padded to the longest of all
        # runs and scans (27 columns for 15 detections on average at 10 clutter points per scan)
        cols = [valid[:, k].any(0).nonzero()[:, 0] for k in range(K)]
        zk = [z[:, k, c] for k, c in enumerate(cols)]
        vk = [valid[:, k, c] for k, c in enumerate(cols)]
        for k in range(K):
            st = self.predict(st, zk[k - 1] if k else None, vk[k - 1] if k else None, g)
            st, part_x, part_w = self.update(st, zk[k], vk[k])
            xe, Pe, me, ee = self.estimate(st, part_x, part_w)
            out["expected"].append(st.expected)
            st = self.resample(st, g)
            out["particles"].append((st.w > 0).sum(1))
            for name, v in (("x", xe), ("P", Pe), ("mass", me), ("exists", ee)):
                out[name].append(v)
            if progress is not None:
                progress(k)
        C = max((v.shape[1] for v in out["x"]), default=0)
        pad = lambda vs, fill: torch.stack([torch.nn.functional.pad(v, (0, 0) * (v.dim() - 2) + (0, C - v.shape[1]),
                                                                    value=fill) for v in vs], 1)
        return PHDEstimates(pad(out["x"], float("nan")), pad(out["P"], 0.0), pad(out["mass"], 0.0),
                            pad(out["exists"], False), torch.stack(out["expected"], 1), torch.stack(out["particles"], 1))
