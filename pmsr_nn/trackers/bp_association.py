"""Data association of one pair by loopy belief propagation (BP), batched over runs and tracks.

The association factor graph of Williams & Lau (IEEE TAES 2014) and Meyer et al. (Proc. IEEE
2018, Sec. VII-VIII), the TOMB/P filter's (Williams, IEEE TAES 2015). At one pair, ``C`` legacy
potential targets (tracks) with existence ``r_i`` and ``M`` detections:

* track ``i`` takes ``a_i in {0 (miss or no target), 1..M}`` with weight
  ``beta_i(0) = 1 - r_i + r_i (1 - Pd)`` and ``beta_i(m) = r_i Pd L_im``, where
  ``L_im = N(z_m; z_hat_i, S_i) / lambda`` inside the gate and 0 outside (``lambda`` the clutter
  density, the caller's likelihood ratio);
* detection ``m`` seeds a new potential target, the undetected targets' Poisson intensity
  through it: it is another track's (``b_m = i``) or not (``b_m = 0``, weight
  ``xi_m = 1 + mu_m``: clutter, or a new target with ``mu_m = mu_b integral f_b(x) Pd
  f(z_m | x) dx / lambda``, the caller's ``birth``);
* a detection is at most one track's, and ``a_i = m`` exactly when ``b_m = i``.

The joint weight of an event (each track at most one detection, each detection at most one
track) is ``prod_i beta_i(a_i) prod_{m free} xi_m``. BP passes messages between the two sets of
variables, in ratio form (Williams & Lau, Eqs. 30-31)::

    mu_{i->m} = beta_i(m) / (beta_i(0) + sum_{m' != m} beta_i(m') nu_{m'->i})
    nu_{m->i} = 1 / (xi_m + sum_{i' != i} mu_{i'->m})

from ``nu = 1``; Williams & Lau prove these iterations converge. The beliefs give the
association probabilities ``p(a_i = m) = beta_i(m) nu_{m->i} / D_i`` and ``p(a_i = 0) =
beta_i(0) / D_i`` (``D_i`` the sum of the numerators), the updated existence of track ``i``
``r_i' = r_i (1 - Pd + Pd sum_m L_im nu_{m->i}) / D_i`` (the IPDA update with the likelihood
ratio ``sum_m L_im nu_{m->i}`` in place of ``sum_m L_im``), and the existence of detection
``m``'s new potential target ``mu_m / (xi_m + sum_i mu_{i->m})``. Where the graph is a tree (one
track, or one detection) BP is exact; on loops it approximates the marginals (measured in
tests/test_bp_association.py).

Shapes: ``B`` runs, ``C`` track slots, ``M`` detections of the pair's list (padded).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class BPAssociation:
    """The BP beliefs of one pair's association.

    ``association (B, C, M + 1)``: ``p(a_i = m)`` for detections ``m < M``, the last column
    ``p(a_i = 0)`` (missed, or no target: the order of
    :func:`~.jpda_associators.pda_marginals`); ``existence (B, C)`` each track's updated
    existence; ``ratio (B, C)`` ``sum_m L_im nu_{m->i}``, the likelihood ratio the IPDA update
    takes to give ``existence``; ``new_existence (B, M)`` the existence of each detection's new
    potential target (0 for padding); ``legacy (B, M)`` the probability that the detection is a
    track's; ``iterations`` the message passes run, ``change`` the last pass's largest change
    of a message ``nu``; ``messages (B, C, M)`` the final ``nu_{m->i}``."""

    association: torch.Tensor
    weights: torch.Tensor
    existence: torch.Tensor
    ratio: torch.Tensor
    new_existence: torch.Tensor
    legacy: torch.Tensor
    iterations: int
    change: float
    messages: torch.Tensor | None = None


def leave_one_out_sum(t: torch.Tensor, dim: int) -> torch.Tensor:
    """``sum_{j != i} t_j`` along ``dim`` for every ``i``, of non-negative ``t``: the sums before
    and after ``i`` added, so no cancellation (``total - t_i`` loses the small sums next to a
    large ``t_i``)."""
    n = t.shape[dim]
    if n == 0:
        return t.clone()
    zero = t.narrow(dim, 0, 1).new_zeros(t.narrow(dim, 0, 1).shape)
    if n == 1:
        return zero
    before = torch.cat([zero, t.narrow(dim, 0, n - 1).cumsum(dim)], dim)
    after = torch.cat([t.narrow(dim, 1, n - 1).flip(dim).cumsum(dim).flip(dim), zero], dim)
    return before + after


def bp_associate(ratio: torch.Tensor, existence: torch.Tensor, pd: float | torch.Tensor,
                 birth: torch.Tensor | None = None, valid: torch.Tensor | None = None, iterations: int = 1000,
                 tolerance: float = 1e-12, start: torch.Tensor | None = None) -> BPAssociation:
    """One pair's association beliefs by BP (module docstring).

    ``ratio (B, C, M)`` ``L_im``, the likelihood of detection ``m`` under track ``i`` over the
    clutter density, 0 outside the gate (and for padding or tracks that gate nothing);
    ``existence (B, C)`` the tracks' predicted existence ``r_i``; ``pd`` the detection
    probability a track's miss term takes (``Pd Pg`` where a gate is applied), a float or
    broadcastable to ``(B, C)`` (below 1 where ``r_i = 1``: a sure target that must be detected
    and gates nothing is an impossible event, its beliefs NaN); ``birth (B, M)`` ``mu_m``, the expected number of new targets
    behind detection ``m`` relative to clutter (None: no births, a free detection is clutter);
    ``valid (B, M)`` the detections that are not padding (None: all). Messages pass until the
    largest change of a ``nu`` is at most ``tolerance`` or ``iterations`` passes are run
    (``tolerance = 0``: a fixed count), from ``nu = 1`` or from ``start (B, C, M)`` (a learned
    tracker's training runs a few differentiable passes from the fixed point it found without
    gradients). Float64 throughout; no Python loop over runs or tracks.
    """
    B, C, M = ratio.shape
    dtype = ratio.dtype
    if valid is not None:
        ratio = torch.where(valid.unsqueeze(1), ratio, 0.0)
    mu_b = ratio.new_zeros(B, M) if birth is None else birth.to(dtype)
    if valid is not None:
        mu_b = torch.where(valid, mu_b, 0.0)
    pd = torch.broadcast_to(torch.as_tensor(pd, dtype=dtype, device=ratio.device), (B, C))
    r = existence.to(dtype)
    beta = (r * pd).unsqueeze(-1) * ratio  # (B, C, M)
    beta0 = 1.0 - r * pd  # (B, C)
    xi = 1.0 + mu_b  # (B, M)
    nu = ratio.new_ones(B, C, M) if start is None else start
    passes, change = 0, 0.0
    while passes < iterations:
        mu = beta / (beta0.unsqueeze(-1) + leave_one_out_sum(beta * nu, -1))  # tracks -> detections
        new = 1.0 / (xi.unsqueeze(1) + leave_one_out_sum(mu, 1))  # detections -> tracks
        change = float((new - nu).detach().abs().max()) if new.numel() else 0.0
        nu = new
        passes += 1
        if change <= tolerance:
            break
    weighted = beta * nu
    D = beta0 + weighted.sum(-1)
    association = torch.cat([weighted, beta0.unsqueeze(-1)], -1) / D.unsqueeze(-1)
    effective = (ratio * nu).sum(-1)
    given = torch.cat([pd.unsqueeze(-1) * ratio * nu, (1.0 - pd).unsqueeze(-1)], -1)
    given = given / given.sum(-1, keepdim=True)
    updated = r * (1.0 - pd + pd * effective) / D
    # the detection side from the final messages (at the fixed point it agrees with the tracks')
    mu = beta / (beta0.unsqueeze(-1) + leave_one_out_sum(beta * nu, -1))
    total = xi + mu.sum(1)
    return BPAssociation(association, given, updated, effective, mu_b / total, mu.sum(1) / total, passes, change, nu)
