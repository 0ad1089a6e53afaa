"""A learned gain inside probabilistic data association: the hybrid tracker on detections.

S-MSJPDA (:mod:`.msjpda`) updates each track sensor by sensor with the mixture of its
association hypotheses; the collapsed mean is ``x_pred + K nu_c``, with ``K = C S^-1`` the UKF
gain and ``nu_c = sum_i alpha_i nu_i`` the innovations of the gated detections weighted by their
association probabilities (a miss contributes none). The hybrid keeps all of that (the
predicted moments, the gate, the association weights, the existence and the track management)
and adds a learned correction of the gain to the mean::

    x = x_pred + (K + dK) nu_c,     dK = scale K + diag(s_x) G diag(1 / s_z),     (scale, G) = net(features, memory)

``scale`` (in (-1, 1)) trusts the model's gain more or less; ``G`` is a gain in units of the
state scale ``s_x`` and the measurement noise deviation ``s_z`` (the physical gain of a 10 km
scene is ~1e-3 m per m, far from what an output layer starts at). The network reads, per track
and sensor, what the association says (:func:`gain_features`: the combined innovation, the miss
probability, how spread the weighted innovations are, the largest weight, how many detections
were gated) and carries a memory per track (a GRU state, cleared when the track's slot is freed).
Its output layer starts at zero, so an untrained network *is* S-MSJPDA; the covariance stays the
model's mixture covariance (it gates and weighs the next scan's detections), so the learned part
moves the estimate only.

This module holds the part the tracker loop needs (:class:`GainCorrection`, the learned part of
the updater: a :class:`~.roles.MeanCorrection` of :class:`~.jpda_associators.SequentialJPDA`);
the network is :class:`pmsr_nn.nets.jpda_gain.GainNet`. The classical trackers never import it.
"""

from __future__ import annotations

from typing import Protocol

import torch


class GainNetwork(Protocol):
    """What :class:`GainCorrection` calls: ``(features (R, F), memory (R, H)) -> (G (R, n, d),
    scale (R,), memory)``, ``F = feature_count(d, n_pairs)``."""

    hidden_size: int
    n_pairs: int

    def __call__(self, features: torch.Tensor, memory: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]: ...


def feature_count(d: int, n_pairs: int) -> int:
    return 3 * d + 4 + n_pairs


def gain_features(pair: int, n_pairs: int, w: torch.Tensor, nu: torch.Tensor, gate: torch.Tensor, S: torch.Tensor,
                  s_z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(nu_c (..., d), features (..., 3 d + 4 + n_pairs))`` of one sensor's association:
    ``w (..., M + 1)`` its weights (the last the miss), ``nu (..., M, d)`` the innovations of its
    ``M`` detections, ``gate (..., M)``, ``S (..., d, d)``.

    Features: the combined innovation ``nu_c / s_z``; the miss probability; the predicted
    deviations ``log(sqrt(diag S) / s_z)``; the spread of the weighted innovations about ``nu_c``
    (diagonal of ``sum_i alpha_i nu_i nu_i^T - nu_c nu_c^T``, over ``diag S``: how much the
    association is in doubt); the largest detection weight; ``log(1 + gated detections)``;
    ``log(1 + nu_c^T S^-1 nu_c)``; the sensor's one-hot."""
    M = nu.shape[-2]
    a = w[..., :M].unsqueeze(-1)
    nu0 = torch.where(gate.unsqueeze(-1), nu, nu.new_zeros(()))
    nu_c = (a * nu0).sum(-2)
    var = torch.diagonal(S, dim1=-2, dim2=-1).clamp(min=1e-30)
    spread = ((a * nu0 * nu0).sum(-2) - nu_c * nu_c).clamp(min=0.0) / var
    nis = (nu_c * torch.linalg.solve(S, nu_c.unsqueeze(-1)).squeeze(-1)).sum(-1).clamp(min=0.0)
    top = w[..., :M].amax(-1) if M else torch.zeros_like(w[..., 0])
    onehot = torch.zeros(*w.shape[:-1], n_pairs, dtype=nu.dtype, device=nu.device)
    onehot[..., pair] = 1.0
    feats = torch.cat([nu_c / s_z, w[..., M:], torch.log(var.sqrt() / s_z), spread, top[..., None],
                       torch.log1p(gate.sum(-1, keepdim=True).to(nu.dtype)), torch.log1p(nis)[..., None], onehot], -1)
    return nu_c, feats


class GainCorrection:
    """The learned gain correction of the tracks of ``B`` runs in ``T`` slots, with their memory.

    ``net`` a :class:`GainNetwork`; ``s_z (d,)`` the deviation of one sensor's measurement
    components, ``s_x (n,)`` the state scale (SI). The tracker calls :meth:`start` once,
    :meth:`step` for every sensor of every scan, and :meth:`forget` where slots were freed.
    The correction is ``dK = scale K + diag(s_x) G diag(1 / s_z)``: ``scale`` in (-1, 1) trusts
    the model's gain ``K`` more or less (e.g. when the association is in doubt), ``G`` adds what a
    rescaled ``K`` can not.

    ``horizon``: a track's memory is cleared every ``horizon`` sensor steps (None: never). A
    network trained on windows of ``L`` scans has never run its memory longer than ``L`` scans of
    ``S`` sensors; beyond that it can drift (measured: one of three seeds trained on 60-scan
    scenes lost its tracks after 100-300 scans), so the method kind sets ``horizon = L S`` and the
    memory always runs as in training.

    ``consistency``: where the combined innovation's ``nu_c^T S^-1 nu_c`` exceeds it, the step uses
    the model's gain alone (no learned part): the covariance that gates and weighs the detections
    is the model's, and a learned mean that has drifted from what it describes must be pulled
    back by the gain it was derived with (None: never).

    ``confirmed_only``: a tracker that manages its tracks applies the correction to its confirmed
    tracks only (tentative tracks are confirmed or dropped by the model's gain alone, so the
    learned part cannot keep a track on clutter alive into confirmation)."""

    def __init__(self, net: GainNetwork, s_z: torch.Tensor, s_x: torch.Tensor, horizon: int | None = None,
                 consistency: float | None = None, confirmed_only: bool = False):
        self.net, self.s_z, self.s_x, self.horizon, self.consistency = net, s_z, s_x, horizon, consistency
        self.confirmed_only = confirmed_only
        self.memory: torch.Tensor | None = None
        self.age: torch.Tensor | None = None

    def start(self, B: int, T: int) -> None:
        """Empty memories of ``B`` runs x ``T`` slots, on the device of the scales ``s_x``."""
        self.memory = torch.zeros(B, T, self.net.hidden_size, device=self.s_x.device)
        self.age = torch.zeros(B, T, dtype=torch.int64, device=self.s_x.device)

    def _grown(self, T: int) -> torch.Tensor:
        """The memory of ``T`` slots (a track table grows; new slots start empty)."""
        B, T0, H = self.memory.shape
        if T > T0:
            self.memory = torch.cat([self.memory, self.memory.new_zeros(B, T - T0, H)], 1)
            self.age = torch.cat([self.age, self.age.new_zeros(B, T - T0)], 1)
        return self.memory

    def step(self, pair: int, w: torch.Tensor, nu: torch.Tensor, gate: torch.Tensor, mom,
             active: torch.Tensor | None) -> torch.Tensor:
        """The mean correction ``dK nu_c (B, T, n)`` (the tracker's dtype) of sensor ``pair``, from
        its association weights ``w (B, T, M + 1)``, innovations ``nu (B, T, M, d)``, gates
        ``gate (B, T, M)`` and predicted moments ``mom`` (``S (B, T, d, d)``, ``C (B, T, n, d)``).
        A track outside ``active (B, T)`` keeps an empty memory and no correction."""
        B, T, M, d = nu.shape
        memory = self._grown(T)
        if self.horizon is not None:
            old = self.age >= self.horizon
            memory = torch.where(old[..., None], memory.new_zeros(()), memory)
            self.age = torch.where(old, 0, self.age)
        s_z = self.s_z.to(nu.dtype)
        nu_c, feats = gain_features(pair, self.net.n_pairs, w, nu, gate, mom.S, s_z)
        params = next(iter(self.net.parameters()), None) if hasattr(self.net, "parameters") else None
        net_dtype = nu.dtype if params is None else params.dtype
        G, scale, new = self.net(feats.to(net_dtype).reshape(B * T, -1), memory.reshape(B * T, -1).to(net_dtype))
        new = new.reshape(B, T, -1)
        G = G.reshape(B, T, -1, d).to(nu.dtype)
        scale = scale.reshape(B, T).to(nu.dtype)
        if active is not None:
            new = torch.where(active[..., None], new, new.new_zeros(()))
            scale = torch.where(active, scale, scale.new_zeros(()))
            G = torch.where(active[..., None, None], G, G.new_zeros(()))
        self.memory = new
        self.age = self.age + 1 if active is None else torch.where(active, self.age + 1, 0)
        K = torch.linalg.solve(mom.S, mom.C.transpose(-1, -2)).transpose(-1, -2)  # C S^-1 (S symmetric)
        dK = scale[..., None, None] * K + self.s_x.to(nu.dtype)[:, None] * G / s_z
        if self.consistency is not None:  # the model's gain alone where the combined innovation is not consistent with S
            nis = (nu_c * torch.linalg.solve(mom.S, nu_c.unsqueeze(-1)).squeeze(-1)).sum(-1)
            dK = torch.where((nis > self.consistency)[..., None, None], dK.new_zeros(()), dK)
        return (dK @ nu_c.unsqueeze(-1)).squeeze(-1)

    def forget(self, where: torch.Tensor) -> None:
        """Clear the memory of the slots ``where (B, C)`` (their tracks were deleted)."""
        memory = self._grown(where.shape[1])
        self.memory = torch.where(where[..., None], memory.new_zeros(()), memory)
        self.age = torch.where(where, 0, self.age)
