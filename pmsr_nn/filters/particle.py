"""Batched bootstrap particle filter (sequential importance resampling) for a batch of runs.

Each run carries ``Np`` particles ``X (B, Np, n)`` and normalised log-weights ``(B, Np)``; runs
and particles are tensor dimensions, the only Python loops are over time and over chunks of runs
(which bound memory). Same convention as :mod:`pmsr_nn.filters.kalman`: particles are drawn from
the prior at step 0 *before* ``z[:, 0]``; step 0 is an update only, every later step first
propagates each particle with the motion model, ``x' = F x + L eps`` (``L L^T = Q``,
``eps ~ N(0, I)``), then updates. The update multiplies each weight by the Gaussian likelihood
``N(z; h(x), R)`` of the wrapped residual (log domain, normalised with logsumexp). The filter
reports the weighted mean and covariance and the effective sample size ``1 / sum w^2`` of the
updated weights, then resamples (systematic) the runs whose ESS fell below
``resample_threshold * Np``; resampled runs get uniform weights.

Missing measurements: NaN entries of ``z`` are marginalised out exactly: the likelihood uses the
sub-covariance of ``R`` over the rows present (any ``R``, diagonal or not). A scan with every
entry missing is a pure prediction (weights unchanged, log-likelihood 0).

Random numbers: every draw comes from the ``generator`` passed in (prior and process-noise normals
via :func:`pmsr_nn.rng.standard_normal`, drawn in float32 and cast; one uniform per run and step
for resampling, drawn whether or not the run resamples; roughening normals only for the runs
that resample).

Lost tracks: if at some step the measurement of a run is so far from every particle that each
Gaussian kernel ``exp(-d^2 / 2)`` underflows in the working dtype (Mahalanobis distance ``d``
above ~37.6 in float64, ~13.2 in float32), the weights carry no information and
:class:`~pmsr_nn.filters.gaussian.FilterError` is raised naming the run and the step; with
``on_lost="flag"`` the step is marked in ``ParticleResult.lost`` instead and the run goes on with
the weights computed in the log domain (finite, dominated by the least unlikely particles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..motion import KinematicModel
from ..rng import standard_normal
from .gaussian import FilterError, Gaussian, symmetrise
from .kalman import check_filter_inputs

CHUNK_BYTES = 1 << 30
"""Default memory budget of one chunk of runs: its particles and one step's temporaries."""

CPU_CHUNK_PARTICLES = 1 << 17
"""On the CPU the default chunk also holds at most this many particles (all runs together): the
per-step work is memory-bound, and on the 2-core development CPU 10^5 to 2x10^5 particles per
chunk run 2x faster than 1.6x10^6 (6.5 against 3.0 M particle-steps/s with 8000 particles)."""

_WORK_COPIES = 6
"""Peak working set of a step in units of ``itemsize * Np * (n + m)`` per run (measured: 5)."""


@dataclass
class ParticleResult:
    """Per run and step: weighted means ``x (B, K, n)``, covariances ``P (B, K, n, n)``, effective
    sample size ``ess (B, K)`` of the updated weights (before resampling, in ``[1, Np]``),
    ``resampled (B, K)`` (the run was resampled after that step's update) and ``log_likelihood
    (B, K)``: log of the weighted mean of the particles' likelihoods ``p(z_k | x_k^i)`` (the
    incremental log marginal-likelihood estimate; 0 for a fully missing scan); ``lost (B, K)``:
    every particle's likelihood underflowed at that step (only with ``on_lost="flag"``)."""

    x: torch.Tensor
    P: torch.Tensor
    ess: torch.Tensor
    resampled: torch.Tensor
    log_likelihood: torch.Tensor
    lost: torch.Tensor


def _systematic_indices(weights: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Systematic resampling of ``weights (B, Np)`` (non-negative, row sums > 0) with one
    uniform ``u (B,)`` in [0, 1) per row -> ancestor indices ``(B, Np)`` (int64, sorted)."""
    Np = weights.shape[-1]
    c = torch.cumsum(weights, dim=-1)
    c = c / c[..., -1:]  # monotone, last entry exactly 1 (no round-off past the end)
    pos = (u.unsqueeze(-1) + torch.arange(Np, dtype=weights.dtype, device=weights.device)) / Np
    # (u + Np - 1) / Np can round up to 1.0 (likely in float32): keep every position below 1.
    pos = pos.clamp_(max=1.0 - torch.finfo(weights.dtype).eps / 2)
    # right=True: position p selects i with c[i-1] <= p < c[i]; zero-weight particles are never chosen.
    return torch.searchsorted(c, pos, right=True)


def systematic_resample(weights: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Ancestor indices ``(B, Np)`` for ``weights (B, Np)`` by systematic resampling.

    One uniform ``u`` per row; the positions ``(u + j) / Np``, ``j = 0..Np-1``, are located in the
    row's cumulative weights (rows are divided by their sum). Particle ``i`` is drawn
    ``floor(Np w_i)`` or ``ceil(Np w_i)`` times and ``Np w_i`` times on average.
    """
    if weights.dim() != 2 or weights.shape[-1] < 1:
        raise ConfigError(f"weights must be (B, Np); got {tuple(weights.shape)}")
    if not weights.is_floating_point() or not bool(torch.isfinite(weights).all()) or bool((weights < 0).any()):
        raise ConfigError("weights must be finite, non-negative floating-point numbers")
    empty = ~(weights.sum(-1) > 0)
    if bool(empty.any()):
        raise ConfigError(f"weights of row {int(empty.nonzero()[0])} are all zero")
    u = torch.rand(weights.shape[0], generator=generator, dtype=weights.dtype, device=weights.device)
    return _systematic_indices(weights, u)


def segmented_resample(x: torch.Tensor, logw: torch.Tensor, comp: torch.Tensor, active: torch.Tensor, counts: torch.Tensor,
              g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Systematic resampling of each active component (a mixture's components, a PHD's runs) to
    ``counts (B, n_components)`` particles, in one pass: with the particles sorted by component and
    each component's weights summing to one, the running sum of all weights passes
    ``c + (i + U) / L`` inside component ``c``'s ``i``-th stratum."""
    B, n_components = counts.shape
    order = torch.argsort(comp, dim=1, stable=True)
    comp_s = comp.gather(1, order)
    w = torch.where(comp_s < n_components, logw.gather(1, order).exp(),
                    torch.zeros((), dtype=logw.dtype, device=logw.device))
    cum = w.cumsum(1)
    base = active.to(w.dtype).cumsum(1) - active.to(w.dtype)  # (B, n_components): components before q
    ends = counts.cumsum(1)
    total = ends[:, -1]
    Mn = int(total.max()) if B else 0
    j = torch.arange(Mn, device=counts.device).expand(B, Mn)
    q = torch.searchsorted(ends, j.contiguous(), right=True).clamp(max=n_components - 1)  # (B, Mn)
    start = (ends - counts).gather(1, q)
    L = counts.gather(1, q).clamp(min=1).to(w.dtype)
    U = torch.rand((B, n_components), generator=g, dtype=w.dtype, device=w.device).gather(1, q)
    target = base.gather(1, q) + ((j - start).to(w.dtype) + U) / L
    idx = torch.searchsorted(cum, target.contiguous())
    # stay inside component q whatever the rounding of the running sum
    first = torch.searchsorted(comp_s.contiguous(), q.contiguous())
    last = torch.searchsorted(comp_s.contiguous(), q.contiguous(), right=True) - 1
    idx = torch.maximum(torch.minimum(idx, last), first).clamp(0, max(comp.shape[1] - 1, 0))
    src = order.gather(1, idx)
    valid = j < total[:, None]
    x_new = x.gather(1, src[..., None].expand(B, Mn, x.shape[-1]))
    comp_new = torch.where(valid, q, torch.full_like(q, n_components))
    logw_new = torch.where(valid, -torch.log(L), torch.full_like(L, -math.inf))
    return x_new, comp_new, logw_new


def _default_chunk_runs(n_particles: int, n: int, m: int, itemsize: int, device: torch.device) -> int:
    runs = CHUNK_BYTES // (_WORK_COPIES * itemsize * n_particles * (n + m))
    if device.type == "cpu":
        runs = min(runs, CPU_CHUNK_PARTICLES // n_particles)
    return max(1, runs)


class _Whitener:
    """``-0.5 d^2 + const`` log-likelihoods of residuals ``nu (b, Np, m)``, missing rows marginalised.

    Holds ``L^-1`` (``L L^T = R``) and ``const = -0.5 log det(2 pi R)``; with missing rows the
    covariance is replaced by the sub-block of the present rows (unit diagonal elsewhere, residual
    zeroed there), which leaves ``d^2`` and ``log det`` of the present rows only.
    """

    def __init__(self, R: torch.Tensor, missing: torch.Tensor | None):
        m = R.shape[-1]
        if missing is not None:
            keep = (~missing).to(R.dtype)
            R = R * keep.unsqueeze(-1) * keep.unsqueeze(-2) + torch.diag_embed(missing.to(R.dtype))
            present = keep.sum(-1)
        else:
            present = torch.tensor(float(m), dtype=R.dtype, device=R.device)
        L = torch.linalg.cholesky(R)  # R passed the positive-definite check; so do its sub-blocks
        eye = torch.eye(m, dtype=R.dtype, device=R.device)
        self.Linv_T = torch.linalg.solve_triangular(L, eye, upper=False).transpose(-1, -2)
        self.const = -torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1) - 0.5 * math.log(2 * math.pi) * present

    def d2(self, nu: torch.Tensor) -> torch.Tensor:
        e = nu @ self.Linv_T  # (b, Np, m) @ (m, m) or (b, m, m)
        return (e * e).sum(-1)

    def log_const(self) -> torch.Tensor:
        c = self.const
        return c.unsqueeze(-1) if c.dim() == 1 else c


def particle_filter(prior: Gaussian, z: torch.Tensor, motion: KinematicModel, dt: float, q, model: MeasurementModel,
                    R: torch.Tensor, n_particles: int = 1000, generator: torch.Generator | None = None,
                    resample_threshold: float = 0.5, chunk_runs: int | None = None,
                    on_lost: str = "raise", roughening: float = 0.0) -> ParticleResult:
    """Bootstrap particle filter over ``z (B, K, m)`` (NaN = missing; m, m/s, rad as the model).

    ``prior``: ``x (B, n)``, ``P (B, n, n)`` or ``(n, n)``; ``dt`` the interval (s); ``q`` the
    motion model's noise intensity, scalar or per run (see :meth:`KinematicModel.Q`); ``R``
    ``(m, m)``, per run ``(B, m, m)`` or per run and step ``(B, K, m, m)``. ``n_particles >= 2``
    per run. ``resample_threshold`` in [0, 1]: resample a run when its ESS falls below
    ``resample_threshold * n_particles`` (0 never, 1 at every step). ``chunk_runs`` runs are
    filtered at a time (all steps of one chunk, then the next); the default keeps a chunk's
    working set below 1 GiB (:data:`CHUNK_BYTES`) and, on the CPU, its particles below
    :data:`CPU_CHUNK_PARTICLES`. Every draw comes from ``generator`` (on ``z``'s device), chunk
    after chunk: the same seed and chunking give the same result, another chunking other (equally
    valid) draws. Computes in ``z``'s dtype and on its device. ``on_lost``: ``"raise"`` a
    :class:`FilterError` when a run's measurement is beyond reach of all its particles (see the
    module notes), or ``"flag"`` it in ``lost`` and go on. ``roughening`` ``K >= 0``: after a
    run is resampled, add to each particle component a normal jitter of deviation
    ``K * (max - min of that component) * Np^(-1/n)`` (roughening, Gordon et al. 1993; 0, the
    default, is the plain bootstrap filter). Needed when the process noise is far below the
    posterior spread (e.g. q = 1e-7 m^2/s^5): resampled copies then never separate and the
    bootstrap filter collapses onto a few particles; ``K = 0.2`` is the usual choice. Roughening
    trades that collapse for over-dispersion (on the nearly noise-free linear case of the
    roughening test the roughened covariance ends far above the exact one), so use its means, not
    its covariances, as a reference.
    """
    check_filter_inputs(prior, z, model, motion, R)
    B, K, m = z.shape
    n = motion.dim_x
    dtype, device = z.dtype, z.device
    if prior.x.dim() != 2 or prior.P.shape not in ((B, n, n), (n, n)):
        raise ConfigError(f"prior must be x (B={B}, {n}) and P (B, {n}, {n}) or ({n}, {n}); "
                          f"got {tuple(prior.x.shape)}, {tuple(prior.P.shape)}")
    if isinstance(n_particles, bool) or not isinstance(n_particles, int) or n_particles < 2:
        raise ConfigError(f"n_particles must be an integer >= 2, got {n_particles!r}")
    if not 0.0 <= float(resample_threshold) <= 1.0:
        raise ConfigError(f"resample_threshold must be in [0, 1], got {resample_threshold}")
    if chunk_runs is not None and (isinstance(chunk_runs, bool) or not isinstance(chunk_runs, int) or chunk_runs < 1):
        raise ConfigError(f"chunk_runs must be a positive integer, got {chunk_runs!r}")
    if not (math.isfinite(roughening) and roughening >= 0):
        raise ConfigError(f"roughening must be a finite number >= 0, got {roughening}")
    if on_lost not in ("raise", "flag"):
        raise ConfigError(f"on_lost must be 'raise' or 'flag', got {on_lost!r}")
    if generator is not None and generator.device.type != device.type:
        raise ConfigError(f"generator is on {generator.device}, measurements on {device}")
    Np = n_particles
    F_T = motion.F(dt, dtype, device).T
    L_q = motion.noise_factor(dt, q, dtype, device)  # (n, n) or per run (B, n, n)
    if L_q.dim() == 3 and L_q.shape[0] != B:
        raise ConfigError(f"per-run q must give {B} runs; got noise factors of shape {tuple(L_q.shape)}")
    if L_q.dim() > 3:
        raise ConfigError(f"q must be a scalar, per run (B,) or per run and axis (B, {motion.spatial_dim}); got {tuple(L_q.shape)}")
    # Only the columns of L that are not zero for every run need draws (CV noise has rank n / 2).
    cols = (L_q != 0).reshape(-1, n, n).any(0).any(0).nonzero().squeeze(-1)
    L_q = L_q[..., cols]
    L0 = torch.linalg.cholesky(prior.P.to(dtype)).expand(B, n, n)
    x0 = prior.x.to(dtype)
    R = R.to(dtype)
    missing_all = torch.isnan(z)
    chunk = chunk_runs or _default_chunk_runs(Np, n, m, torch.finfo(dtype).bits // 8, device)
    # A particle's kernel exp(-d^2 / 2) underflows (is below the smallest normal number) beyond this.
    d2_max = -2.0 * math.log(torch.finfo(dtype).tiny)

    out = ParticleResult(z.new_empty(B, K, n), z.new_empty(B, K, n, n), z.new_empty(B, K),
                         torch.zeros(B, K, dtype=torch.bool, device=device), z.new_empty(B, K),
                         torch.zeros(B, K, dtype=torch.bool, device=device))
    for lo in range(0, B, chunk):
        hi = min(lo + chunk, B)
        b = hi - lo
        L_k = L_q[lo:hi] if L_q.dim() == 3 else L_q
        static = None if R.dim() == 4 else _Whitener(R[lo:hi] if R.dim() == 3 else R, None)
        X = x0[lo:hi, None, :] + standard_normal((b, Np, n), generator, dtype, device) @ L0[lo:hi].transpose(-1, -2)
        logw = torch.full((b, Np), -math.log(Np), dtype=dtype, device=device)
        step_has_missing = missing_all[lo:hi].any(-1).any(0).tolist()  # one device sync per chunk
        for k in range(K):
            if k > 0:
                eps = standard_normal((b, Np, len(cols)), generator, dtype, device)
                X = X @ F_T + eps @ L_k.transpose(-1, -2)
            zk = z[lo:hi, k]
            missing = missing_all[lo:hi, k]
            any_missing = step_has_missing[k]
            R_k = R[lo:hi, k] if R.dim() == 4 else (R[lo:hi] if R.dim() == 3 else R)
            white = _Whitener(R_k, missing if any_missing else None) if (any_missing or static is None) else static
            z_fill = torch.where(missing, 0.0, zk) if any_missing else zk
            nu = model.residual(z_fill.unsqueeze(-2), model.h(X))  # (b, Np, m)
            if any_missing:
                nu = torch.where(missing.unsqueeze(-2), 0.0, nu)
            d2 = white.d2(nu)
            lost = ~(d2.amin(-1) <= d2_max)  # NaN propagates through amin: caught here too
            if bool(lost.any()):
                bad = ~torch.isfinite(d2).all(-1)
                if bool(bad.any()):
                    raise FilterError(f"likelihood of run {lo + int(bad.nonzero()[0])} became non-finite at step {k}")
                if on_lost == "flag":
                    out.lost[lo:hi, k] = lost
                else:
                    r = int(lost.nonzero()[0])
                    raise FilterError(f"all particle weights of run {lo + r} underflow at step {k}: the measurement "
                                      f"is {float(d2[r].amin()) ** 0.5:.3g} standard deviations (Mahalanobis) from "
                                      "every particle (lost track or outlier; check z, R, q and the prior, or pass "
                                      "on_lost='flag')")
            ll = white.log_const() - 0.5 * d2  # (b, Np)
            lv = logw + ll
            lse = torch.logsumexp(lv, dim=-1)  # (b,)
            if any_missing:  # a fully missing scan leaves the weights exactly as they were
                lse = torch.where(missing.all(-1), 0.0, lse)
            logw = lv - lse.unsqueeze(-1)
            w = torch.exp(logw)
            ess = 1.0 / (w * w).sum(-1)
            mean = (w.unsqueeze(-2) @ X).squeeze(-2)  # (b, n)
            D = X - mean.unsqueeze(-2)
            out.x[lo:hi, k] = mean
            out.P[lo:hi, k] = symmetrise((D * w.unsqueeze(-1)).transpose(-1, -2) @ D)
            out.ess[lo:hi, k] = ess
            out.log_likelihood[lo:hi, k] = lse
            # One uniform per run at every step, whether or not a run resamples: the stream of draws
            # does not depend on the data.
            u = torch.rand(b, generator=generator, dtype=dtype, device=device)
            do = ess < resample_threshold * Np if resample_threshold < 1 else torch.ones_like(ess, dtype=torch.bool)
            if bool(do.any()):
                out.resampled[lo:hi, k] = do
                if bool(do.all()):
                    idx = _systematic_indices(w, u)
                    X = torch.gather(X, 1, idx.unsqueeze(-1).expand(-1, -1, n))
                    logw = torch.full_like(logw, -math.log(Np))
                else:
                    idx = _systematic_indices(w[do], u[do])
                    X[do] = torch.gather(X[do], 1, idx.unsqueeze(-1).expand(-1, -1, n))
                    logw[do] = -math.log(Np)
            if roughening > 0 and bool(do.any()):
                # Gordon, Salmond and Smith (1993): jitter resampled particles by
                # K * (spread of each component) * Np^(-1/n), so that copies of one particle
                # separate again when the process noise is too small to do it.
                Xr = X[do]
                scale = (roughening * Np ** (-1.0 / n)) * (Xr.amax(1) - Xr.amin(1))  # (r, n)
                X[do] = Xr + standard_normal(Xr.shape, generator, dtype, device) * scale.unsqueeze(1)
    return out
