"""Initiators: tentative tracks from the detections no track explains, batched over runs.

Two components with one interface (``check(model, what)`` refuses a model in one line;
``initiate(z, unused, model, n, other_sd) -> (Gaussian (B, G, n), real (B, G))``), used by every
tracker that starts its own tracks through :class:`~.management.Management`:

* :class:`~.fix_initiator.FixInitiator`: each pair measures azimuth, so each detection fixes a
  position; fixes of different pairs that agree form a track;
* :class:`~.spherical_initiator.SphericalInitiator`: bistatic range and range-rate (or Doppler)
  only; every combination of one detection per pair is fitted and gated, the best consistent
  ones start tracks.

Both fit the velocity from the rate component with :func:`velocity_fit` (here, with
:func:`rate_component`). Shapes: ``B`` runs, ``S`` pairs, ``M`` detections per list, ``d``
components per pair, ``n`` state dimension, ``G`` tracks started, ``D`` spatial dimension.
"""

from __future__ import annotations

import torch

from ..measurements import MeasurementModel


def rate_component(model: MeasurementModel) -> int | None:
    """Index of the rate component (``range_rate`` in m/s or ``doppler`` in Hz, the first of
    them) among ``model.components``; ``None`` if the model measures neither."""
    rate = [c for c in model.components if c in ("range_rate", "doppler")]
    return model.components.index(rate[0]) if rate else None


def velocity_fit(model: MeasurementModel, x: torch.Tensor, z: torch.Tensor, has: torch.Tensor,
                 precision: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Velocity ``(..., D)`` (m/s) and its covariance ``(..., D, D)`` at the positions of states
    ``x (..., n)``: the linear least-squares fit of the rate component (:func:`rate_component`)
    of detections ``z (..., S, d)`` (one per pair ``s`` of ``model``, used where ``has (..., S)``)
    under the prior ``N(0, precision^-1)`` (``precision (D, D)`` in (s/m)^2). A rate row is linear
    in velocity at a known position (its gradient is the model's Jacobian row by velocity, which
    does not depend on the velocity). Without a rate component: the prior."""
    vi = list(model.vel_idx)
    D = len(vi)
    Lam = precision.expand(*x.shape[:-1], D, D).clone()
    eta = x.new_zeros(*x.shape[:-1], D)
    c = rate_component(model)
    if c is not None:
        var = model.noise_std[c] ** 2
        for s in range(has.shape[-1]):
            g = model.for_pairs([s]).jacobian(x)[..., c, :][..., vi]  # (..., D)
            w = has[..., s].to(x.dtype) / var
            zr = torch.where(has[..., s], z[..., s, c], x.new_zeros(()))
            Lam = Lam + w[..., None, None] * g.unsqueeze(-1) * g.unsqueeze(-2)
            eta = eta + (w * zr)[..., None] * g
    Pv = torch.linalg.inv(Lam)
    return (Pv @ eta.unsqueeze(-1)).squeeze(-1), Pv
