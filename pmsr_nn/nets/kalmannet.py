"""A KalmanNet-style tracker: the EKF's predict/update structure with a learned gain.

After Revach et al., "KalmanNet: Neural network aided Kalman filtering for partially known
dynamics", IEEE TSP 70, 2022 (our own code). Per scan ``k``::

    x_pred = F x_{k-1}                       known CA motion (the recipe's dt)
    nu     = z_k - h(x_pred)                 known bistatic measurement model, angles wrapped
    K_k    = gain(features_k)                a GRU replaces the covariance recursion
    x_k    = x_pred + K_k nu

The gain network reads the four features of KalmanNet's second architecture, each scaled to
O(1): the observation difference ``z_k - z_{k-1}`` and the innovation ``nu`` (per measurement
row, divided by that row's noise deviation on the training split), the forward evolution
difference ``x_{k-1} - x_{k-2}`` and the forward update difference ``x_{k-1} - x_pred_{k-1}``
(divided by the state-fix error deviation per state column). Its output ``G (n, m)`` is the gain
in those units, ``K = diag(s_x) G diag(1 / s_z)``: the physical gain of a 10 km-range scene is
~1e-3 m per m, far from what a network's output layer starts at.

The filter starts at each sequence's first state fix (:mod:`pmsr_nn.filters.fixes`; acceleration
zero), so, like every learned tracker, it reads only measurements. A filter that has lost the target
is re-started (``restart_gate``, :meth:`KalmanNetTracker.restarts`): where the normalised
innovation ``|nu| / s_z`` exceeds the gate in as many rows as there are pairs, the filter starts
afresh at the scan's own state fix (GRU state zero, as at a window's first scan), provided that
fix agrees with its scan's measurements (every row within the gate). The case it is for: one range
outlier (10x) can put a scan's fix on the wrong branch of the range equations, 3-20 km off (0.02-
0.04 % of the mismatch study's scans); a window started there cannot come back through innovations
clipped at ``innovation_clip`` deviations (~90 m a scan), and the sliding-window inference
(:mod:`pmsr_nn.nets.inference`) restarts a window every 50 scans. The network's inputs are the
measurements in SI units followed by the state fixes (``inputs: measurements_and_fixes``) and its
outputs the correction to the fix (``output: residual``), so it trains, checkpoints and tracks
through the same code as the MDFNN. :class:`EKFGain` puts the EKF's own gain in the network's
place: the tests check that the structure then reproduces :func:`~pmsr_nn.filters.ekf`.
"""

from __future__ import annotations

import torch
from torch import nn

from ..filters.gaussian import Gaussian, kalman_gain, linearised_moments, symmetrise
from ..measurements import MeasurementModel
from ..motion import ConstantAcceleration
from .config import ModelConfig


class KalmanNetTracker(nn.Module):
    """``u (B, K, m + n) -> y (B, K, n)``: measurements (SI) and state fixes in, correction to the
    fix (in units of ``state_scale``) out. Causal with unbounded memory (``context == (None, 0)``)."""

    def __init__(self, cfg: ModelConfig, model: MeasurementModel, dt: float, noise_scale: torch.Tensor,
                 state_scale: torch.Tensor):
        super().__init__()
        self.cfg = cfg
        self.model = model
        m, n = model.dim_z, len(state_scale)
        self.m, self.n = m, n
        motion = ConstantAcceleration(spatial_dim=n // 3)
        self.register_buffer("F", motion.F(dt, torch.float32))
        self.register_buffer("s_z", noise_scale.float())
        self.register_buffer("s_x", state_scale.float())
        width = cfg.rnn_hidden
        self.inp = nn.Sequential(nn.Linear(2 * m + 2 * n, width), nn.ReLU())
        self.gru = nn.GRUCell(width, width)
        self.out = nn.Linear(width, n * m)
        nn.init.zeros_(self.out.weight)  # a zero gain at the start: the filter coasts on the first fix
        nn.init.zeros_(self.out.bias)

    @property
    def context(self) -> tuple[int | None, int]:
        return None, 0

    def learned_gain(self, features: torch.Tensor, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(K (B, n, m) in SI, new hidden state)`` from ``features (B, 2m + 2n)``."""
        hidden = self.gru(self.inp(features), hidden)
        G = self.out(hidden).view(-1, self.n, self.m) * self.cfg.gain_scale
        return self.s_x[:, None] * G / self.s_z, hidden

    def filter(self, z: torch.Tensor, fix0: torch.Tensor, gain=None, fixes: torch.Tensor | None = None) -> torch.Tensor:
        """Filtered states ``(B, K, n)`` (SI) of ``z (B, K, m)`` started at ``fix0 (B, n)``.

        ``gain``: None for the network; else a callable ``(x_pred, nu) -> K (B, n, m)`` (e.g.
        :class:`EKFGain`) that replaces it. ``fixes (B, K, n)``: every scan's state fix, which a
        lost filter is re-started at (``restart_gate``; without them, or with a ``gain``, never)."""
        B, K, _ = z.shape
        x = fix0
        x_prev, x_pred_prev = x, x
        hidden = z.new_zeros(B, self.gru.hidden_size) if gain is None else None
        F = self.F.to(z.dtype)
        restart = fixes is not None and self.cfg.restart_gate is not None
        out = [x]
        for k in range(1, K):
            if gain is None:
                x_new, x_pred, hidden = self.step(z[:, k], z[:, k - 1], x, x_prev, x_pred_prev, hidden)
                if restart:
                    r = self.restarts(z[:, k], x_pred, fixes[:, k])
                    if bool(r.any()):  # as at a window's first scan: the fix, no history, GRU state zero
                        f, rr = fixes[:, k].to(x_new.dtype), r[:, None]
                        x, x_pred, x_new = (torch.where(rr, f, v) for v in (x, x_pred, x_new))
                        hidden = torch.where(rr, torch.zeros_like(hidden), hidden)
            else:
                x_pred = x @ F.T
                nu = self.model.residual(z[:, k], self.model.h(x_pred))
                x_new = x_pred + (gain(x_pred, nu) @ nu.unsqueeze(-1)).squeeze(-1)
            x_prev, x_pred_prev, x = x, x_pred, x_new
            out.append(x)
        return torch.stack(out, 1)

    def step(self, z: torch.Tensor, z_prev: torch.Tensor, x: torch.Tensor, x_prev: torch.Tensor,
             x_pred_prev: torch.Tensor, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One scan with the learned gain: ``(x_k, x_pred_k, hidden_k)`` from the scan's measurements
        ``z (B, m)``, the previous scan's ``z_prev``, the filtered states ``x = x_{k-1}`` and
        ``x_prev = x_{k-2}``, the previous prediction ``x_pred_prev`` (all ``(B, n)``, SI) and the
        GRU state ``hidden (B, H)``. (The ONNX export runs this as its per-scan graph.)"""
        x_pred = x @ self.F.to(z.dtype).T
        nu = self.model.residual(z, self.model.h(x_pred))
        if self.cfg.innovation_clip is not None:  # bounded influence of an outlier (Huber-like)
            c = self.cfg.innovation_clip * self.s_z
            nu = torch.maximum(torch.minimum(nu, c), -c)
        feats = torch.cat([self.model.residual(z, z_prev) / self.s_z, nu / self.s_z,
                           (x - x_prev) / self.s_x, (x - x_pred_prev) / self.s_x], -1)
        if self.cfg.innovation_clip is not None:
            feats = feats.clamp(-10 * self.cfg.innovation_clip, 10 * self.cfg.innovation_clip)
        K, hidden = self.learned_gain(feats.to(self.s_x.dtype), hidden)
        x_new = x_pred + (K.to(z.dtype) @ nu.unsqueeze(-1)).squeeze(-1)
        return x_new, x_pred, hidden

    def restarts(self, z: torch.Tensor, x_pred: torch.Tensor, fix: torch.Tensor) -> torch.Tensor:
        """``(B,)`` bool: where the filter re-starts at this scan's fix ``fix (B, n)``: it has lost
        the target (at least as many rows of ``|z - h(x_pred)| / s_z`` as there are pairs exceed
        ``restart_gate``: a position kilometres off misses every pair's range, one outlier moves
        one row) and the fix agrees with its own scan ``z (B, m)`` (every row of
        ``|z - h(fix)| / s_z`` within the gate: a fix on the wrong branch misses the azimuths by
        tens of deviations). Never where ``restart_gate`` is null."""
        g = self.cfg.restart_gate
        if g is None:
            return torch.zeros(z.shape[0], dtype=torch.bool, device=z.device)
        fix = fix.to(z.dtype)
        beyond = (self.model.residual(z, self.model.h(x_pred)) / self.s_z).abs() > g
        lost = beyond.sum(-1) >= self.model.n_pairs
        agrees = (self.model.residual(z, self.model.h(fix)) / self.s_z).abs().amax(-1) <= g
        return lost & agrees & torch.isfinite(fix).all(-1)

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        z, fix = u[..., : self.m], u[..., self.m :]
        x = self.filter(z, fix[:, 0], fixes=fix)
        return (x - fix) / self.s_x


class EKFGain:
    """The EKF's gain in KalmanNet's place: carries ``P`` through ``P = F P F^T + Q`` and
    ``K = P H^T (H P H^T + R)^-1``, ``P = P - K S K^T`` (the update of :mod:`pmsr_nn.filters`)."""

    def __init__(self, P0: torch.Tensor, F: torch.Tensor, Q: torch.Tensor, model: MeasurementModel, R: torch.Tensor):
        self.P, self.F, self.Q, self.model, self.R = P0, F, Q, model, R

    def __call__(self, x_pred: torch.Tensor, nu: torch.Tensor) -> torch.Tensor:
        P = self.F @ self.P @ self.F.T + self.Q
        m = linearised_moments(Gaussian(x_pred, P), self.model, self.R)  # S = H P H^T + R, C = P H^T
        K = kalman_gain(m)
        self.P = symmetrise(P - K @ m.C.transpose(-1, -2))  # K S K^T = C S^-1 C^T = K C^T
        return K
