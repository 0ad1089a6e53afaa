"""A learned gain inside probabilistic data association: the hybrid tracker on detections.

S-MSJPDA (:mod:`.msjpda`) updates each track sensor by sensor with the mixture of its
association hypotheses; the collapsed mean is ``x_pred + K nu_c``, with ``K = C S^-1`` the UKF
gain and ``nu_c = sum_i alpha_i nu_i`` the innovations of the gated detections weighted by their
association probabilities (a miss contributes none). The hybrid keeps all of that (the
predicted moments, the gate, the association weights, the existence and the track management)
and adds a learned correction of the gain to the mean::

    x = x_pred + (K + dK) nu_c,      dK = diag(s_x) G diag(1 / s_z),   G = net(features, memory)

``G`` is what the network outputs per track and sensor, in units of the state scale ``s_x`` and
the measurement noise deviation ``s_z`` (the physical gain of a 10 km scene is ~1e-3 m per m, far
from what an output layer starts at). The network reads, per track and sensor, the combined
innovation ``nu_c / s_z``, the miss probability ``alpha_miss``, the predicted measurement
deviations ``log(sqrt(diag S) / s_z)`` and which sensor it is, and carries a memory per track
(a GRU state, cleared when the track's slot is freed). Its output layer starts at zero, so an
untrained network *is* S-MSJPDA; the covariance stays the model's mixture covariance (it
gates and weighs the next scan's detections), so the learned part moves the estimate only.

This module holds the part the tracker loop needs (``pda_marginals``, :class:`GainCorrection`);
the network is :class:`pmsr_nn.nets.jpda_gain.GainNet`.
"""

from __future__ import annotations

import math
from typing import Literal, Protocol

import torch

from .jpda import miss_cost

Association = Literal["jpda", "pda"]


def pda_marginals(log_lik: torch.Tensor, gated: torch.Tensor, pd: float, density: float) -> torch.Tensor:
    """Association probabilities of each track on its own (PDA, no competition between tracks).

    ``log_lik (..., M)`` ``log N(z_i; z_hat, S)``, ``gated (..., M)`` bool. A gated detection
    weighs ``Pd N_i / lambda``, the miss ``1 - Pd`` (the costs of :mod:`.jpda`, so with one track
    and fewer gated detections than the JPDA's ``m_best`` both agree). Returns ``alpha (..., M + 1)``,
    the last column the miss. Batched over every axis: no loop, differentiable in nothing (the
    weights are constants to a learned gain).
    """
    det = torch.where(gated, log_lik + math.log(pd) - math.log(density), torch.tensor(-math.inf, dtype=log_lik.dtype))
    miss = torch.full((*log_lik.shape[:-1], 1), -miss_cost(pd), dtype=log_lik.dtype)
    return torch.softmax(torch.cat([det, miss], -1), -1)


class GainNetwork(Protocol):
    """What :class:`GainCorrection` calls: ``(features (R, F), memory (R, H)) -> (G (R, n, d), memory)``."""

    hidden_size: int
    n_pairs: int

    def __call__(self, features: torch.Tensor, memory: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]: ...


def gain_features(pair: int, n_pairs: int, nu_c: torch.Tensor, miss: torch.Tensor, S: torch.Tensor,
                  s_z: torch.Tensor) -> torch.Tensor:
    """``(..., 2 d + 1 + n_pairs)``: ``nu_c / s_z``, ``alpha_miss``, ``log(sqrt(diag S) / s_z)`` and
    the sensor's one-hot, from ``nu_c (..., d)``, ``miss (...)`` and ``S (..., d, d)``."""
    sd = torch.diagonal(S, dim1=-2, dim2=-1).clamp(min=1e-30).sqrt()
    onehot = torch.zeros(*miss.shape, n_pairs, dtype=nu_c.dtype, device=nu_c.device)
    onehot[..., pair] = 1.0
    return torch.cat([nu_c / s_z, miss[..., None], torch.log(sd / s_z), onehot], -1)


class GainCorrection:
    """The learned gain correction of the tracks of ``B`` runs in ``T`` slots, with their memory.

    ``net`` a :class:`GainNetwork`; ``s_z (d,)`` the deviation of one sensor's measurement
    components, ``s_x (n,)`` the state scale (SI). The tracker calls :meth:`start` once,
    :meth:`step` for every sensor of every scan, and :meth:`forget` where slots were freed."""

    def __init__(self, net: GainNetwork, s_z: torch.Tensor, s_x: torch.Tensor):
        self.net, self.s_z, self.s_x = net, s_z, s_x
        self.memory: torch.Tensor | None = None

    def start(self, B: int, T: int) -> None:
        self.memory = torch.zeros(B, T, self.net.hidden_size)

    def _grown(self, T: int) -> torch.Tensor:
        """The memory of ``T`` slots (a track table grows; new slots start empty)."""
        B, T0, H = self.memory.shape
        if T > T0:
            self.memory = torch.cat([self.memory, self.memory.new_zeros(B, T - T0, H)], 1)
        return self.memory

    def step(self, pair: int, nu_c: torch.Tensor, miss: torch.Tensor, S: torch.Tensor,
             active: torch.Tensor | None) -> torch.Tensor:
        """The mean correction ``dK nu_c (B, T, n)`` (the tracker's dtype) of sensor ``pair``, from
        ``nu_c (B, T, d)``, ``miss (B, T)`` and ``S (B, T, d, d)``. A track outside ``active (B, T)``
        keeps an empty memory and no correction."""
        B, T, d = nu_c.shape
        memory = self._grown(T)
        s_z = self.s_z.to(nu_c.dtype)
        params = next(iter(self.net.parameters()), None) if hasattr(self.net, "parameters") else None
        net_dtype = nu_c.dtype if params is None else params.dtype
        feats = gain_features(pair, self.net.n_pairs, nu_c, miss, S, s_z).to(net_dtype).reshape(B * T, -1)
        G, new = self.net(feats, memory.reshape(B * T, -1).to(feats.dtype))
        new = new.reshape(B, T, -1)
        G = G.reshape(B, T, -1, d).to(nu_c.dtype)
        if active is not None:
            new = torch.where(active[..., None], new, torch.zeros((), dtype=new.dtype))
            G = torch.where(active[..., None, None], G, torch.zeros((), dtype=G.dtype))
        self.memory = new
        dK = self.s_x.to(nu_c.dtype)[:, None] * G / s_z
        return (dK @ nu_c.unsqueeze(-1)).squeeze(-1)

    def forget(self, where: torch.Tensor) -> None:
        """Clear the memory of the slots ``where (B, C)`` (their tracks were deleted)."""
        memory = self._grown(where.shape[1])
        self.memory = torch.where(where[..., None], torch.zeros((), dtype=memory.dtype), memory)
