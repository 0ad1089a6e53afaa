"""Probabilistic multi-hypothesis tracking (PMHT, Streit & Luginbuhl 1995) and its 3-D
(target-detection-illuminator) association variant of Li et al., JEIT 2021, over a sliding batch
of scans, all Monte Carlo runs at once: :func:`pmht` here, its settings and inputs in
:mod:`.pmht_model`, one EM iteration on a window in :mod:`.pmht_em`, and PMHT with track
management in :mod:`.pmht_managed`.

Model
-----
``N`` targets, each present at every scan (:func:`pmht`: tracks start from a prior at scan 0;
no birth or death; :func:`~.pmht_managed.managed_pmht` starts and ends its own, below).
Detections arrive in *lists*: one per transmitter-receiver pair when each detection's illuminator
is known, one per receiver in a single-frequency network (SFN), where it is not. Detection ``r``
was caused by clutter (uniform over the measurement box of volume ``V``) or by target ``t`` through
one of the pairs ``A_r`` that can have produced it (every pair of its receiver in an SFN, its own
pair otherwise), independently of the other detections: PMHT's assumption, which lets a target
cause several detections of a list and makes the association posterior factor over detections.
With fixed association priors written as rates (Pd per target and pair, clutter rate
``lambda_s`` per pair), each detection's density is the mixture

    p(z_r | X) = [lambda_A / V + sum_{t, s in A_r, p} Pd c_p N(z_r; h_s(x_t), kappa_p R_s)] / const,

``lambda_A = sum_{s in A_r} lambda_s``. The Gaussian scale mixture (``kappa_p`` with weights
``c_p``) is the paper's "equal means, different covariances" (Section 3.2); one component with
``kappa = 1`` is plain PMHT. The priors are fixed (from Pd and the clutter rate), not estimated.

EM over a window of scans (MAP estimate of the states ``X`` of every target at every scan)
-------------------------------------------------------------------------------------------
* E-step (Eq. 20): the posterior weight of every (detection, target, pair, component), with runs,
  scans, lists, detections, targets, pairs and components as tensor axes.
* M-step (Eqs. 21-25): per target and pair one synthetic measurement, the weighted mean of the
  detections with weights ``w / kappa`` (taken as residuals about the current prediction, so an
  angle would average correctly), with covariance ``R_s / sum(w / kappa)``. The paper's Eq. 25
  divides by ``sum(w)``; the maximiser of its Eq. 21 has the ``1 / kappa`` (they agree for one
  component). Then an unscented Kalman smoother per target: a UKF over the synthetic
  measurements and the RTS backward pass (the CV transition is linear, where the unscented RTS
  pass of :mod:`~pmsr_nn.filters.smoothing` equals the linear one). A pair whose summed weight is
  below ``min_weight`` gives no synthetic measurement.
* Annealing (optional, ``anneal``): the first iterations of a batch use an inflated measurement
  covariance, shrinking to ``R`` by the middle (:meth:`~.pmht_model.PMHTSettings.inflation`), so that EM
  started several deviations from the detections (a loose initiation) still finds them.
* Marginal E-step (optional, ``e_step = "marginal"``): each detection is weighed by
  ``N(z_r; h_s(x_t), kappa_p R_s + H P H^T)`` under the track's current covariance ``P`` instead of
  at its point estimate, so that a track started several deviations off weighs what its own
  uncertainty covers (issue 37: with the point E-step such tracks settled on another target's
  detections through one pair, or on none, in the first window). EM's objective is then no
  longer the one below.
* With a linear measurement model the M-step is exact and the objective (:func:`~.pmht_em.window_objective`:
  the log prior of the window's first state, the transitions and every detection's mixture
  density) never decreases over iterations; with the bistatic model the UKF's linearisation makes
  the M-step approximate.

Sliding window: ``window`` scans, advancing by ``window - overlap`` (the last window ends at the
last scan). The scans leaving a window keep its smoothed estimates (a fixed-lag smoother, not
causal); the next window's prior is the last iteration's forward filter predicted to its first
scan, so no detection counts twice; EM starts from the previous smoothed states on the overlap
and their CV prediction beyond.

Track management (:mod:`.pmht_managed`)
---------------------------------------
The tracks of :mod:`.management` (a table of slots, an initiator, M-of-N confirmation, a
deleter, IPDA existence) in the sliding window: EM runs on every slot, a free one explaining no
detection; after EM, each scan the window commits reads the association weights (a hit where a
track's summed weight at a pair is >= 0.5, a start from the detections whose weight on all
tracks is < 0.5), and a track started at a scan of the window joins EM from that scan on.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..filters.gaussian import Gaussian
from ..motion import KinematicModel
from .pmht_em import em_step, window_objective
from .pmht_model import AssociationLists, PMHTProblem, PMHTSettings, check_lists, problem


@dataclass
class PMHTResult:
    """Smoothed means ``x (B, K, N, n)`` and covariances ``P (B, K, N, n, n)``; ``objective``: per
    window, ``(iterations + 1, B)`` values of :func:`~.pmht_em.window_objective` (only when asked for)."""

    x: torch.Tensor
    P: torch.Tensor
    objective: list[torch.Tensor] | None = None


def window_starts(K: int, s: PMHTSettings) -> list[int]:
    """First scan of each window: every ``step`` scans; the last window ends at the last scan."""
    if s.window > K:
        raise ConfigError(f"PMHT window of {s.window} scans is longer than the {K} scans of the scenario")
    starts = [0]
    while starts[-1] + s.window < K:
        starts.append(min(starts[-1] + s.step, K - s.window))
    return starts


def pmht(lists: AssociationLists, prior: Gaussian, motion: KinematicModel, dt: float, q, model, R: torch.Tensor,
         settings: PMHTSettings, record_objective: bool = False) -> PMHTResult:
    """PMHT on ``lists`` (``K`` scans), tracks from ``prior`` (``x (B, N, n)`` at scan 0).

    ``model``: the pair-layout measurement model (``h`` of a state gives every pair's ``d``
    values) or any model with ``h``, ``angle_rows``, ``residual`` and ``dim_z`` (one pair);
    ``R (S d, S d)`` block-diagonal. ``record_objective`` keeps :func:`~.pmht_em.window_objective` after
    every iteration (for checks; it costs one more E-step each).
    """
    n = motion.dim_x
    S = getattr(model, "n_pairs", 1)
    check_lists(lists, prior, S, n)
    B, K = lists.z.shape[:2]
    N = prior.x.shape[1]
    dtype, device = prior.x.dtype, prior.x.device
    pr = problem(model, motion, dt, q, R, settings, dtype, device)
    starts = window_starts(K, settings)
    x_out = torch.empty(B, K, N, n, dtype=dtype, device=device)
    P_out = torch.empty(B, K, N, n, n, dtype=dtype, device=device)
    history = [] if record_objective else None
    for c0 in range(0, B, settings.chunk_runs):
        runs = slice(c0, min(B, c0 + settings.chunk_runs))
        b = runs.stop - runs.start
        g = Gaussian(prior.x[runs].reshape(b * N, n), prior.P[runs].reshape(b * N, n, n))
        X_prev = P_prev = None
        marginal = settings.e_step == "marginal"
        for i, a in enumerate(starts):
            W = min(settings.window, K - a)
            nxt = starts[i + 1] if i + 1 < len(starts) else K
            win = lists.take(runs, slice(a, a + W))
            shift = a - starts[i - 1] if i else 0
            X = initial_states(pr, g, X_prev, shift, W, b, N)
            P = initial_covariances(pr, g, P_prev, shift, W, b, N) if marginal else None
            win_prior = Gaussian(g.x.reshape(b, N, n), g.P.reshape(b, N, n, n))
            record = [window_objective(pr, X, win_prior, win)] if record_objective else None
            for it in range(settings.em_iterations):
                # the point E-step reads no covariance: only the last iteration's are kept
                need_P = marginal or settings.tolerance_m > 0 or it == settings.em_iterations - 1
                X_new, P, handed, _ = em_step(pr, X, g, win, settings.inflation(it), nxt - a,
                                              P=P if marginal else None, covariances=need_P)
                moved = (X_new - X)[..., list(motion.pos_idx)].norm(dim=-1).max()
                X = X_new
                if record is not None:
                    record.append(window_objective(pr, X, win_prior, win))
                if settings.tolerance_m > 0 and float(moved) < settings.tolerance_m:
                    break
            done = nxt - a
            x_out[runs, a:a + done] = X[:, :done]
            P_out[runs, a:a + done] = P[:, :done]
            g, X_prev, P_prev = handed, X, P
            if record is not None:
                history.append(torch.stack(record))
    return PMHTResult(x_out, P_out, history)


def initial_states(pr: PMHTProblem, g: Gaussian, X_prev: torch.Tensor | None, shift: int, W: int, b: int, N: int) -> torch.Tensor:
    """EM's starting states ``(b, W, N, n)``: the previous window's smoothed states on the overlap,
    CV predictions beyond (the prior's mean predicted through the first window)."""
    n = pr.F.shape[0]
    if X_prev is None:
        cur, out = g.x.reshape(b, N, n), []
    else:
        keep = X_prev[:, shift:]
        out = list(keep.unbind(1))[:W]
        cur = keep[:, -1] @ pr.F.transpose(-1, -2)
    while len(out) < W:
        out.append(cur)
        cur = cur @ pr.F.transpose(-1, -2)
    return torch.stack(out, 1)


def initial_covariances(pr: PMHTProblem, g: Gaussian, P_prev: torch.Tensor | None, shift: int, W: int, b: int,
                        N: int) -> torch.Tensor:
    """Covariances ``(b, W, N, n, n)`` of :func:`initial_states` (for the marginal E-step): the
    previous window's smoothed ones on the overlap, predicted (``F P F^T + Q``) beyond; in the first
    window the prior's, predicted through it."""
    n = pr.F.shape[0]
    if P_prev is None:
        cur, out = g.P.reshape(b, N, n, n), []
    else:
        keep = P_prev[:, shift:]
        out = list(keep.unbind(1))[:W]
        cur = pr.F @ keep[:, -1] @ pr.F.T + pr.Q
    while len(out) < W:
        out.append(cur)
        cur = pr.F @ cur @ pr.F.T + pr.Q
    return torch.stack(out, 1)
