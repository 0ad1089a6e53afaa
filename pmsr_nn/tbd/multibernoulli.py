"""SMC multi-Bernoulli track-before-detect on range-Doppler maps: PMB, ICMB and the modified ICMB.

The posterior is a set of Bernoulli components ``(r_q, p_q)``, each density a cloud of weighted
particles (Vo et al. 2010, the seed's Eqs. 6-8 and 21-27). One frame:

1. *prediction*: particles through the CV model, ``r <- p_S r``; one birth component with
   ``r_birth`` and particles uniform over the birth box (the seed's choice);
2. *online SNR estimate* (``estimate_snr``): per map, the largest of the particles'
   maximum-likelihood amplitudes (:func:`~.likelihood.ml_amplitude`, Eq. 25; ``snr_estimator:
   max``), or that with its bias removed (``bootstrap``, :mod:`.snr`); it also orders the maps;
3. *update*: ``product`` (PMB, Eq. 16: one update with the product of the maps' ratios) or one map
   after another (ICMB, Eqs. 26-27) in the order ``ascending`` / ``descending`` of the SNRs used
   (given, or estimated). A component's ``r <- r m / (1 - r + r m)`` with ``m`` the weighted mean of
   its particles' likelihood ratios; the weights are multiplied by the ratios and renormalised;
4. estimates: every component with ``r`` above ``threshold`` (its weighted mean);
5. pruning (``r < prune``); suppression and merging. Two components whose means fall within
   ``merge_doppler_cells`` and the range triangle's half-width of each other in a map share that
   map's cells, which the likelihood (one target per neighbourhood of cells, the seed's Section
   3.2.1) does not allow: sharing them in *every* map, they are one target and merge (the
   particles of both weighted by ``r``, ``r = min(r_1 + r_2, r_max)``); sharing them in some maps
   only, the weaker is a ghost living off the stronger's energy there and is dropped. Without this
   a birth that locks onto the target already held, or onto its echo in one or two maps, stays
   with ``r`` near 1;
   systematic resampling of each component to ``L_q = clip(r_q L_max, L_min, L_max)`` particles.

Batching: all runs of a block at once. A run's particles live in one flat, padded array ``(B, M)``
with the component of each (``comp``; the padding belongs to a spare slot ``Q``), so particle
counts adapt per component and per run without a loop over either. Component slots ``(B, Q)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Literal

import torch

from ..config import require
from ..filters.particle import segmented_resample
from .likelihood import gather_cells, log_likelihood_ratio, max_ml_amplitude
from .snr import SNR_ESTIMATORS, SnrEstimator, bootstrap_ml_amplitude

UpdateOrder = Literal["product", "ascending", "descending", "given"]


@dataclass(frozen=True)
class BirthBox:
    """Uniform birth density over ``x_m``, ``y_m``, ``vx_mps``, ``vy_mps`` (each ``[lo, hi]``)."""

    x_m: tuple[float, float] = (138_000.0, 144_000.0)
    y_m: tuple[float, float] = (-5_000.0, 5_000.0)
    vx_mps: tuple[float, float] = (-50.0, -20.0)
    vy_mps: tuple[float, float] = (80.0, 140.0)

    def __post_init__(self) -> None:
        for name in ("x_m", "y_m", "vx_mps", "vy_mps"):
            lo, hi = getattr(self, name)
            require(math.isfinite(lo) and math.isfinite(hi) and lo < hi, f"birth_box.{name} must be [lo, hi] with lo < hi")

    def bounds(self, device=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower and upper corners ``(4,)`` in the CV state order ``[x, vx, y, vy]`` (on ``device``)."""
        corner = lambda i: [self.x_m[i], self.vx_mps[i], self.y_m[i], self.vy_mps[i]]
        return tuple(torch.tensor(corner(i), dtype=torch.float64, device=device) for i in (0, 1))


@dataclass(frozen=True)
class MBSpec:
    """Settings of the SMC multi-Bernoulli filter (defaults: the seed's, where it gives them).

    ``snr_model_db``: the SNR (per map, or one for all) the likelihood assumes; ``None`` with
    ``estimate_snr`` false means the true SNRs (known-SNR study). ``snr_estimator``: how
    ``estimate_snr`` estimates (:mod:`.snr`: ``max`` the seed's, ``bootstrap`` with its bias
    removed over ``snr_replicas`` replica maps and the ``snr_kept_states`` best states);
    ``snr_candidates``: the states whose ML amplitude is iterated (the largest starting values).
    ``subarea_half``: sub-area ``(2h+1)^2`` (``None``: the whole map). ``accel_sd_mps2``: the CV
    model's white acceleration deviation (the seed gives no Q)."""

    update: UpdateOrder = "ascending"
    estimate_snr: bool = False
    snr_model_db: tuple[float, ...] | None = None
    subarea_half: int | None = 2
    particles_min: int = 2000
    particles_max: int = 10_000
    birth_particles: int = 10_000
    birth_r: float = 0.01
    survival: float = 0.95
    prune: float = 1e-3
    threshold: float = 0.5
    r_max: float = 0.999
    merge_doppler_cells: float = 1.0
    accel_sd_mps2: float = 0.05
    max_components: int = 24
    ml_iterations: int = 30
    snr_estimator: SnrEstimator = "max"
    snr_candidates: int = 256
    snr_replicas: int = 4
    snr_kept_states: int = 32
    roughening: float = 0.0
    ghost_rule: Literal["shared", "evidence"] = "shared"
    ghost_evidence: float = 3.0

    def __post_init__(self) -> None:
        require(self.update in ("product", "ascending", "descending", "given"),
                f"update must be product, ascending, descending or given, got {self.update!r}")
        require(1 <= self.particles_min <= self.particles_max,
                f"particles_min ({self.particles_min}) must be at least 1 and at most particles_max ({self.particles_max})")
        require(self.birth_particles >= 1, "birth_particles must be at least 1")
        require(0 < self.birth_r < 1 and 0 < self.survival <= 1 and 0 <= self.prune < self.threshold < 1,
                "need 0 < birth_r < 1, 0 < survival <= 1 and 0 <= prune < threshold < 1")
        require(self.snr_model_db is None or all(math.isfinite(v) for v in self.snr_model_db),
                f"snr_model_db must be finite, got {self.snr_model_db}")
        require(self.subarea_half is None or self.subarea_half >= 0, "subarea_half must be >= 0 (or null: whole map)")
        require(self.accel_sd_mps2 >= 0 and self.merge_doppler_cells >= 0, "negative deviation or gate")
        require(self.max_components >= 2, "max_components must be at least 2")
        require(self.snr_estimator in SNR_ESTIMATORS,
                f"snr_estimator must be one of {', '.join(SNR_ESTIMATORS)}, got {self.snr_estimator!r}")
        require(self.snr_candidates >= 1 and self.snr_replicas >= 1 and self.snr_kept_states >= 1,
                "snr_candidates, snr_replicas and snr_kept_states must be at least 1")
        require(self.ghost_rule in ("shared", "evidence"), f"ghost_rule must be shared or evidence, got "
                                                           f"{self.ghost_rule!r}")
        require(math.isfinite(self.ghost_evidence), "ghost_evidence must be finite (nats)")
        require(math.isfinite(self.roughening) and self.roughening >= 0,
                f"roughening must be a finite number >= 0, got {self.roughening}")


@dataclass
class MBOutput:
    """Per run and frame: ``x (B, K, Q, 4)`` component means, ``r (B, K, Q)`` existence after the
    update (0 for free slots), ``snr_db (B, K, P)`` the SNRs the update used (estimated or given),
    ``order (B, K, P)`` the maps' update order, ``particles (B, K)`` the particles after resampling,
    ``born (B, K)`` the slot the frame's birth went into (a slot's component is a new one from then
    on: slots are reused)."""

    x: torch.Tensor
    r: torch.Tensor
    snr_db: torch.Tensor
    order: torch.Tensor
    particles: torch.Tensor
    born: torch.Tensor | None = None

    def best(self, threshold: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The most probable component per run and frame: its mean ``(B, K, 4)``, whether its ``r``
        exceeds ``threshold`` ``(B, K)``, and that ``r`` ``(B, K)``."""
        r, q = self.r.max(-1)
        x = self.x.gather(2, q[..., None, None].expand(*q.shape, 1, 4))[:, :, 0]
        return x, r > threshold, r


def _segment_logsumexp(values: torch.Tensor, comp: torch.Tensor, slots: int) -> torch.Tensor:
    """Per run and component slot ``(B, slots)``: log of the sum of ``exp(values)`` over its particles."""
    B = values.shape[0]
    top = values.new_full((B, slots), -math.inf).scatter_reduce(1, comp, values, "amax")
    safe = torch.where(torch.isfinite(top), top, top.new_zeros(()))
    s = values.new_zeros((B, slots)).scatter_add(1, comp, torch.exp(values - safe.gather(1, comp)))
    return torch.log(s) + safe


@dataclass
class MBState:
    """Particles ``x (B, M, 4)``, log weights normalised per component ``logw (B, M)`` (``-inf``:
    padding), component of each particle ``comp (B, M)`` (``Q`` = padding), existence ``r (B, Q)``
    (0: free slot)."""

    x: torch.Tensor
    logw: torch.Tensor
    comp: torch.Tensor
    r: torch.Tensor

    @property
    def Q(self) -> int:
        return self.r.shape[1]


class MapLikelihood:
    """The maps' likelihood ratios of states (the seed's filter): ``maps(k) -> (B, P, D, U)``
    gives frame ``k``'s maps, ``cells(x, k) -> (d, u)`` the fractional cells ``(B, M, P)`` of states
    ``x (B, M, 4)`` at frame ``k``; ``true_snr_db (P,)`` the scenario's, used when ``spec`` models
    none and estimates none, on the maps' device; ``g``: the generator of the ``bootstrap``
    estimate's replica maps, of that device."""

    def __init__(self, spec: MBSpec, maps: Callable, cells: Callable, lobe_cells: float, noise_power: float,
                 true_snr_db: torch.Tensor, g: torch.Generator | None = None):
        self.spec, self.maps, self.cells = spec, maps, cells
        self.lobe_cells, self.noise_power = lobe_cells, noise_power
        self.true_snr_db = true_snr_db.to(torch.float64)
        require(not (spec.estimate_snr and spec.snr_estimator == "bootstrap") or g is not None,
                "the bootstrap SNR estimate needs a generator for its replica maps")
        self.g = g

    def modelled_snr(self, B: int, P: int) -> torch.Tensor:
        s = self.spec.snr_model_db
        if s is None:
            return self.true_snr_db.expand(B, P)
        snr = torch.tensor(s, dtype=torch.float64, device=self.true_snr_db.device)
        return snr.expand(B, P)  # one value for every map, or one per map

    def __call__(self, x: torch.Tensor, valid: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Log ratios ``(B, M, P)`` of states ``x (B, M, 4)`` and the SNRs ``(B, P)`` (dB) used."""
        spec = self.spec
        z = self.maps(k).abs()
        B, P = z.shape[:2]
        d, u = self.cells(x, k)
        cv = gather_cells(z, d, u, self.lobe_cells, spec.subarea_half)
        if spec.estimate_snr:
            if spec.snr_estimator == "bootstrap":
                a = bootstrap_ml_amplitude(z.shape[1:], d, u, cv, valid, self.lobe_cells, spec.subarea_half,
                                           self.noise_power, spec.ml_iterations, spec.snr_candidates,
                                           spec.snr_replicas, spec.snr_kept_states, self.g)
            else:
                a = max_ml_amplitude(cv, valid, self.noise_power, spec.ml_iterations, spec.snr_candidates)
            snr = 20 * torch.log10(a.to(torch.float64).clamp(min=1e-12) / math.sqrt(self.noise_power))  # (B, P)
        else:
            snr = self.modelled_snr(B, P)
        amp = torch.sqrt(self.noise_power * 10.0 ** (snr / 10))[:, None, :]  # (B, 1, P)
        return log_likelihood_ratio(cv, amp, self.noise_power).to(torch.float64), snr


class MultiBernoulliTBD:
    """The filter for one block of ``B`` runs: ``measure(x, valid, k) -> (loglr (B, M, P), snr_db
    (B, P))`` gives each state's log likelihood ratio per map at frame ``k`` and the SNRs that order
    the maps (:class:`MapLikelihood`, or detections: :mod:`.detect`); ``cells(x, k)`` the states'
    fractional cells (merging); ``F``, ``noise_factor``: the CV model over one frame for unit
    acceleration variance; ``lobe_cells``: the range triangle's half-width. Its tensors are on
    ``F``'s device (the maps'), ``g`` a generator of that device."""

    def __init__(self, spec: MBSpec, box: BirthBox, lobe_cells: float, F: torch.Tensor, noise_factor: torch.Tensor):
        self.spec, self.box, self.lobe_cells = spec, box, lobe_cells
        self.F, self.L = F, noise_factor

    def run(self, K: int, measure: Callable, cells: Callable, B: int, g: torch.Generator) -> MBOutput:
        spec = self.spec
        Q = spec.max_components
        dev = self.F.device
        zeros = lambda *shape, dtype=torch.float64: torch.zeros(shape, dtype=dtype, device=dev)
        st = MBState(zeros(B, 0, 4), zeros(B, 0), zeros(B, 0, dtype=torch.int64), zeros(B, Q))
        xs, rs, snrs, orders, counts, born = [], [], [], [], [], []
        lo, hi = self.box.bounds(dev)
        for k in range(K):
            st = self._predict(st, g) if k else st
            st, slot = self._birth(st, lo, hi, g)
            born.append(slot)
            loglr, snr = measure(st.x, st.comp < Q, k)
            P = loglr.shape[-1]
            order = torch.argsort(snr, dim=1, descending=spec.update == "descending", stable=True)
            if spec.update == "given":
                order = torch.arange(P, device=dev).expand(B, P)
            evidence = self._evidence(st, loglr) if spec.ghost_rule == "evidence" else None
            st = self._update(st, loglr, order)
            st = self._prune_merge(st, cells(self._components(st)[0], k), evidence)
            x_q, r_q = self._components(st)  # the estimates come after pruning and merging (the seed's order)
            xs.append(x_q)
            rs.append(r_q)
            snrs.append(snr)
            orders.append(order)
            st = self._resample(st, g)
            counts.append((st.comp < Q).sum(1))
        return MBOutput(torch.stack(xs, 1), torch.stack(rs, 1), torch.stack(snrs, 1), torch.stack(orders, 1),
                        torch.stack(counts, 1), torch.stack(born, 1))

    # ------------------------------------------------------------------ stages

    def _predict(self, st: MBState, g: torch.Generator) -> MBState:
        B, M, _ = st.x.shape
        w = torch.randn((B, M, self.L.shape[-1]), generator=g, dtype=torch.float64, device=st.x.device)
        x = st.x @ self.F.T + w @ self.L.T * self.spec.accel_sd_mps2
        return MBState(x, st.logw, st.comp, st.r * self.spec.survival)

    def _birth(self, st: MBState, lo: torch.Tensor, hi: torch.Tensor, g: torch.Generator) -> tuple[MBState, torch.Tensor]:
        """One new component per run in its first free slot (the weakest is dropped when none is
        free); also returns that slot ``(B,)``."""
        B, Q = st.r.shape
        n = self.spec.birth_particles
        free = st.r <= 0
        weakest = torch.where(free, torch.full_like(st.r, -1.0), st.r).argmin(1)  # a free slot scores -1
        slot = torch.where(free.any(1), free.to(torch.int64).argmax(1), weakest)
        dropped = torch.zeros_like(free).scatter_(1, slot[:, None], True)
        comp = torch.where(dropped.gather(1, st.comp.clamp(max=Q - 1)) & (st.comp < Q), torch.full_like(st.comp, Q), st.comp)
        logw = torch.where(comp < Q, st.logw, torch.full_like(st.logw, -math.inf))
        xb = lo + (hi - lo) * torch.rand((B, n, 4), generator=g, dtype=torch.float64, device=lo.device)
        r = st.r.scatter(1, slot[:, None], self.spec.birth_r)
        logw_b = torch.full((B, n), -math.log(n), dtype=torch.float64, device=logw.device)
        return MBState(torch.cat([st.x, xb], 1), torch.cat([logw, logw_b], 1),
                       torch.cat([comp, slot[:, None].expand(B, n)], 1), r), slot

    def _bernoulli_update(self, st: MBState, loglr: torch.Tensor) -> MBState:
        """Eqs. 7-8 (or 26-27 for one map): ``loglr (B, M)`` per particle."""
        Q = st.Q
        lw = torch.where(st.comp < Q, st.logw + loglr, torch.full_like(st.logw, -math.inf))
        log_m = _segment_logsumexp(lw, st.comp, Q + 1)[:, :Q]  # (B, Q): log of the mean ratio
        active = st.r > 0
        log_m = torch.where(active, log_m, log_m.new_zeros(()))
        logit = torch.log(st.r.clamp(min=1e-300)) - torch.log1p(-st.r.clamp(max=1 - 1e-15))
        r = torch.where(active, torch.sigmoid(logit + log_m), st.r)
        norm = torch.cat([log_m, torch.zeros_like(log_m[:, :1])], 1).gather(1, st.comp)
        return MBState(st.x, lw - norm, st.comp, r)

    def _update(self, st: MBState, loglr: torch.Tensor, order: torch.Tensor) -> MBState:
        if self.spec.update == "product":
            return self._bernoulli_update(st, loglr.sum(-1))
        for i in range(loglr.shape[-1]):
            st = self._bernoulli_update(st, loglr.gather(2, order[:, None, i:i + 1].expand(-1, loglr.shape[1], 1))[..., 0])
        return st

    def _components(self, st: MBState) -> tuple[torch.Tensor, torch.Tensor]:
        """Weighted means ``(B, Q, 4)`` and existence ``(B, Q)`` of the components."""
        B, Q = st.r.shape
        w = torch.where(st.comp < Q, st.logw.exp(), st.logw.new_zeros(()))
        mean = torch.zeros(B, Q + 1, 4, dtype=torch.float64, device=st.x.device).index_put_(
            (torch.arange(B, device=st.comp.device)[:, None].expand_as(st.comp), st.comp), w[..., None] * st.x,
            accumulate=True)[:, :Q]
        return mean, st.r.clone()

    def _evidence(self, st: MBState, loglr: torch.Tensor) -> torch.Tensor:
        """Each component's evidence per map ``(B, Q, P)``: the log of its predicted particles' mean
        likelihood ratio in that map alone (0 for a free slot)."""
        Q = st.Q
        lw = torch.where((st.comp < Q)[..., None], st.logw[..., None] + loglr, torch.full_like(loglr, -math.inf))
        ev = torch.stack([_segment_logsumexp(lw[..., p], st.comp, Q + 1)[:, :Q] for p in range(loglr.shape[-1])], -1)
        return torch.where((st.r > 0)[..., None], ev, ev.new_zeros(()))

    def _prune_merge(self, st: MBState, mean_cells: tuple, evidence: torch.Tensor | None = None) -> MBState:
        """``mean_cells``: the fractional cells ``(d, u)``, each ``(B, Q, P)``, of the components' means;
        ``evidence (B, Q, P)``: :meth:`_evidence` (``ghost_rule: evidence``), else None."""
        spec = self.spec
        B, Q = st.r.shape
        r = torch.where(st.r >= spec.prune, st.r, st.r.new_zeros(()))
        active = r > 0
        # merging: each component joins the most probable other one close to it, when that one is more probable
        d, u = mean_cells
        near = (((d[:, :, None] - d[:, None, :]).abs() <= spec.merge_doppler_cells)
                & ((u[:, :, None] - u[:, None, :]).abs() <= self.lobe_cells))  # (B, Q, Q, P)
        pair = active[:, :, None] & active[:, None, :]
        q_idx = torch.arange(Q, device=r.device)
        stronger = (r[:, None, :] > r[:, :, None]) | ((r[:, None, :] == r[:, :, None])
                                                       & (q_idx[None, None, :] < q_idx[None, :, None]))
        # sharing cells in some maps only: the weaker explains the stronger's energy there (a ghost)
        partial = near & ~near.all(-1, keepdim=True) & (pair & stronger)[..., None]  # (B, Q, Q, P)
        if evidence is None:
            ghost = partial.any(-1).any(2)
        else:  # unless the maps it shares with no stronger component hold evidence of its own
            shared = partial.any(2)  # (B, Q, P)
            own = torch.where(shared, evidence.new_zeros(()), evidence).sum(-1)
            ghost = shared.any(-1) & (own < spec.ghost_evidence)
        r = torch.where(ghost, r.new_zeros(()), r)
        active = r > 0
        close = near.all(-1) & active[:, :, None] & active[:, None, :]
        cand = torch.where(close & stronger, r[:, None, :], torch.full_like(close, -1.0, dtype=r.dtype))
        best_r, target = cand.max(2)
        target = torch.where(best_r > 0, target, q_idx.expand(B, Q))  # self: no merge
        target = target.gather(1, target)  # one hop further: chains join their head
        into = r.new_zeros(B, Q).scatter_add(1, target, r)
        r_new = torch.where(target == q_idx, into.clamp(max=spec.r_max), r.new_zeros(()))
        # particle weights within the merged component: r_source w / sum r
        comp_full = torch.cat([target, target.new_full((B, 1), Q)], 1)
        r_full = torch.cat([r, r.new_zeros(B, 1)], 1)
        into_full = torch.cat([into, into.new_ones(B, 1)], 1)
        new_comp = comp_full.gather(1, st.comp)
        keep = (new_comp < Q) & (r_full.gather(1, st.comp) > 0)
        logw = st.logw + torch.log(r_full.gather(1, st.comp).clamp(min=1e-300)) - torch.log(into_full.gather(1, new_comp))
        logw = torch.where(keep, logw, torch.full_like(logw, -math.inf))
        new_comp = torch.where(keep, new_comp, torch.full_like(new_comp, Q))
        return MBState(st.x, logw, new_comp, r_new)

    def _resample(self, st: MBState, g: torch.Generator) -> MBState:
        spec = self.spec
        counts = torch.where(st.r > 0, (st.r * spec.particles_max).round().clamp(spec.particles_min, spec.particles_max),
                             st.r.new_zeros(())).to(torch.int64)
        x, comp, logw = segmented_resample(st.x, st.logw, st.comp, st.r > 0, counts, g)
        if spec.roughening > 0:
            x = self._roughen(x, comp, st.Q, g)
        return MBState(x, logw, comp, st.r)

    def _roughen(self, x: torch.Tensor, comp: torch.Tensor, Q: int, g: torch.Generator) -> torch.Tensor:
        """Gordon et al.'s (1993) roughening of each component's resampled particles ``x (B, M, 4)``:
        a normal jitter of deviation ``K (max - min) L^(-1/4)`` per coordinate, ``L`` the
        component's particles. Without it the CV model's small process noise leaves a resampled
        cloud a few distinct states that no later map can move (sample impoverishment over
        hundreds of frames)."""
        B, M, n = x.shape
        at = comp[..., None].expand(B, M, n)
        lo = x.new_full((B, Q + 1, n), math.inf).scatter_reduce(1, at, x, "amin")
        hi = x.new_full((B, Q + 1, n), -math.inf).scatter_reduce(1, at, x, "amax")
        count = x.new_zeros(B, Q + 1).scatter_add(1, comp, torch.ones_like(x[..., 0]))
        sd = self.spec.roughening * torch.nan_to_num(hi - lo, posinf=0.0, neginf=0.0) \
            * count.clamp(min=1)[..., None] ** (-1.0 / n)
        w = torch.randn((B, M, n), generator=g, dtype=x.dtype, device=x.device)
        return x + w * sd.gather(1, at)  # the padding's slot Q has no spread: its zeros stay
