"""PMHT's inputs and model (:mod:`.pmht`): settings, detections as association lists, and what
every window of scans shares (models, per-pair noise factors, the measurement mixture).

Shapes: ``B`` runs, ``K`` scans, ``L`` lists per scan, ``M`` detections per list, ``S`` pairs,
``d`` values per pair, ``n`` state dimension, ``N`` targets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.gaussian import Gaussian, SigmaPoints, safe_cholesky
from .. import SPEED_OF_LIGHT
from ..measurements import MIN_SENSOR_DISTANCE_M, MeasurementModel
from ..motion import KinematicModel
from ..simulation.detections import PooledScans, Scans


E_STEPS = ("point", "marginal")
"""How the E-step weighs a detection: at the point estimate, ``N(z; h(x), kappa R)`` (PMHT as
published), or under the track's Gaussian, ``N(z; h(x), kappa R + H P H^T)``
(:func:`~.pmht_em.marginal_covariances`)."""


@dataclass(frozen=True)
class PMHTSettings:
    """``pd``: detection probability per target and pair; ``clutter_rate (S,)``: expected clutter
    detections per scan attributed to each pair (> 0); ``volume``: the measurement box's volume in
    SI units (m Hz for range-Doppler); ``window`` scans per batch, ``overlap`` scans shared by
    consecutive batches; ``em_iterations`` per batch (at most: EM stops earlier once no position
    moves more than ``tolerance_m``, 0 = never); ``kappa`` covariance scales of the measurement
    mixture with ``kappa_weights`` (default equal); ``anneal``: the measurement covariance of the
    first EM iteration of a batch is ``anneal`` times ``R`` (:meth:`inflation`); ``e_step``: one
    of :data:`E_STEPS`; ``chunk_runs``: runs per pass (bounds memory)."""

    pd: float
    clutter_rate: tuple[float, ...]
    volume: float
    window: int = 10
    overlap: int = 3
    em_iterations: int = 6
    tolerance_m: float = 0.0
    kappa: tuple[float, ...] = (1.0,)
    kappa_weights: tuple[float, ...] | None = None
    anneal: float = 1.0
    e_step: str = "point"
    min_weight: float = 1e-9
    chunk_runs: int = 64

    def __post_init__(self) -> None:
        require(0.0 < self.pd <= 1.0, f"pd must be in (0, 1], got {self.pd}")
        require(all(r > 0 and math.isfinite(r) for r in self.clutter_rate) and len(self.clutter_rate) > 0,
                f"clutter rates must be positive (a tracker needs a clutter model), got {self.clutter_rate}")
        require(self.volume > 0 and math.isfinite(self.volume), f"volume must be positive, got {self.volume}")
        require(self.window >= 1, f"window must be at least 1 scan, got {self.window}")
        require(0 <= self.overlap < self.window, f"overlap must be in [0, window - 1], got {self.overlap}")
        require(self.em_iterations >= 1, f"em_iterations must be at least 1, got {self.em_iterations}")
        require(self.tolerance_m >= 0, f"tolerance_m must be >= 0, got {self.tolerance_m}")
        require(len(self.kappa) >= 1 and all(k > 0 and math.isfinite(k) for k in self.kappa),
                f"kappa must be positive covariance scales, got {self.kappa}")
        w = self.kappa_weights
        require(w is None or (len(w) == len(self.kappa) and all(v > 0 for v in w)),
                f"kappa_weights must be one positive weight per kappa, got {w}")
        require(self.min_weight > 0 and self.chunk_runs >= 1, "min_weight must be positive and chunk_runs >= 1")
        require(self.anneal >= 1 and math.isfinite(self.anneal), f"anneal must be >= 1, got {self.anneal}")
        require(self.e_step in E_STEPS, f"e_step must be one of {E_STEPS}, got {self.e_step!r}")

    def inflation(self, iteration: int) -> float:
        """Annealing (homotopy) of the measurement covariance: iteration ``i`` (0-based) of a batch
        uses ``a_i R``, ``a_i = anneal^(1 - i / h)`` for ``i < h = em_iterations // 2``, then 1. EM
        from a start far from the detections (several deviations: a loose initiation prior) sees
        them through the wider covariance first; the last iterations are plain EM."""
        h = self.em_iterations // 2
        return self.anneal ** (1 - iteration / h) if iteration < h and self.anneal > 1 else 1.0

    @property
    def step(self) -> int:
        return self.window - self.overlap

    def mixture(self, dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
        """``kappa (P,)`` and the log of the normalised weights ``(P,)``."""
        kappa = torch.tensor(self.kappa, dtype=dtype, device=device)
        w = torch.tensor(self.kappa_weights or [1.0] * len(self.kappa), dtype=dtype, device=device)
        return kappa, (w / w.sum()).log()


@dataclass
class AssociationLists:
    """Detections as PMHT reads them: ``z (B, K, L, M, d)``, ``valid (B, K, L, M)`` and
    ``candidates (B, K, L, M, S)`` bool, the pairs that may have produced each detection."""

    z: torch.Tensor
    valid: torch.Tensor
    candidates: torch.Tensor

    @classmethod
    def per_pair(cls, scans: Scans) -> "AssociationLists":
        """Illuminator known: one list per pair, each detection from its list's pair."""
        B, K, S, M = scans.shape
        eye = torch.eye(S, dtype=torch.bool, device=scans.z.device)
        return cls(scans.z, scans.valid, eye[:, None, :].expand(B, K, S, M, S))

    @classmethod
    def pooled(cls, pooled: PooledScans, labels_known: bool = False) -> "AssociationLists":
        """One list per receiver; the candidates are the receiver's pairs, or (``labels_known``,
        for checks) each detection's true pair."""
        s = pooled.scans
        B, K, L, M = s.shape
        S = pooled.routes.shape[1]
        if labels_known:
            cand = pooled.pair.unsqueeze(-1) == torch.arange(S, device=s.z.device)
        else:
            cand = pooled.routes.to(s.z.device)[:, None, :].expand(B, K, L, M, S)
        return cls(s.z, s.valid, cand)

    def take(self, runs: slice, scans: slice = slice(None)) -> "AssociationLists":
        return AssociationLists(self.z[runs, scans], self.valid[runs, scans], self.candidates[runs, scans])


@dataclass
class PMHTProblem:
    """What every window shares: models, per-pair noise factors and the settings."""

    model: object
    F: torch.Tensor
    Q: torch.Tensor
    R: torch.Tensor  # (S d, S d) block-diagonal
    R_inv_chol: torch.Tensor  # (S, d, d): L_s^-1 with L_s L_s^T = R_s
    R_blocks: torch.Tensor  # (S, d, d): R_s
    log_det: torch.Tensor  # (S,): log det R_s
    angles: torch.Tensor  # (d,) bool
    rate: torch.Tensor  # (S,)
    kappa: torch.Tensor  # (P,)
    log_c: torch.Tensor  # (P,)
    sigma: tuple  # (wm, wc, scale) of the UKF's sigma points
    settings: PMHTSettings
    h: object = None  # model.h, or an equal one with fewer tensor operations (pair_h)

    def __post_init__(self) -> None:
        if self.h is None:
            self.h = self.model.h

    @property
    def pairs(self) -> int:
        return self.R_inv_chol.shape[0]


_BISTATIC = ("range", "delay", "range_rate", "doppler")


def pair_h(model, dtype=torch.float64, device=None):
    """``model.h`` for a pair-layout :class:`~pmsr_nn.measurements.MeasurementModel` of bistatic
    range / delay / range-rate / Doppler components, written over ``(..., S, D)`` tensors: about
    a third of the tensor operations of ``model.h`` (which keeps coordinates apart for large
    batches), equal to rounding; what the UKF calls per scan on a few sigma points. Any other
    model: ``model.h`` itself."""
    if (not isinstance(model, MeasurementModel) or model.layout != "pair"
            or not set(model.components) <= set(_BISTATIC)):
        return model.h
    tx = model.geometry.pair_tx_positions(dtype, device)  # (S, D)
    rx = model.geometry.pair_rx_positions(dtype, device)
    fc = model.geometry.pair_carriers(dtype, device)[:, None]  # (S, 1)
    pos = torch.tensor(model.pos_idx, device=device)
    vel = torch.tensor(model.vel_idx, device=device)
    comps = model.components

    def h(x: torch.Tensor) -> torch.Tensor:
        p = x[..., None, pos]  # (..., 1, D)
        off_t, off_r = p - tx, p - rx  # (..., S, D)
        d_t = torch.linalg.vector_norm(off_t, dim=-1, keepdim=True).clamp_min(MIN_SENSOR_DISTANCE_M)
        d_r = torch.linalg.vector_norm(off_r, dim=-1, keepdim=True).clamp_min(MIN_SENSOR_DISTANCE_M)
        rows, rng, rate = [], d_t + d_r, None  # (..., S, 1)
        for c in comps:
            if c in ("range", "delay"):
                rows.append(rng if c == "range" else rng / SPEED_OF_LIGHT)
            else:
                if rate is None:
                    rate = (x[..., None, vel] * (off_t / d_t + off_r / d_r)).sum(-1, keepdim=True)
                rows.append(rate if c == "range_rate" else rate * (-fc / SPEED_OF_LIGHT))
        return torch.cat(rows, -1).flatten(-2)  # (..., S C): [r_1, fd_1, r_2, fd_2, ...]

    return h


def problem(model, motion: KinematicModel, dt: float, q, R: torch.Tensor, s: PMHTSettings, dtype=torch.float64,
            device=None) -> PMHTProblem:
    """Everything the windows share (one-line errors for a model or ``R`` PMHT can not use)."""
    S = getattr(model, "n_pairs", 1)
    if getattr(model, "layout", "pair") != "pair":
        raise ConfigError("PMHT reads detections per pair: the measurement model needs layout 'pair'")
    if len(s.clutter_rate) != S:
        raise ConfigError(f"{len(s.clutter_rate)} clutter rates for {S} pairs")
    d = model.dim_z // S
    R = R.to(dtype=dtype, device=device)
    blocks = torch.stack([R[i * d:(i + 1) * d, i * d:(i + 1) * d] for i in range(S)])
    off = R.clone()
    for i in range(S):
        off[i * d:(i + 1) * d, i * d:(i + 1) * d] = 0
    if bool((off != 0).any()):
        raise ConfigError("PMHT needs R block-diagonal across pairs (independent sensors)")
    L = safe_cholesky(blocks)
    eye = torch.eye(d, dtype=dtype, device=device).expand_as(L)
    kappa, log_c = s.mixture(dtype, device)
    return PMHTProblem(model, motion.F(dt, dtype, device), motion.Q(dt, q, dtype, device), R,
                    torch.linalg.solve_triangular(L, eye, upper=False), blocks,
                    2 * torch.log(torch.diagonal(L, dim1=-2, dim2=-1)).sum(-1), model.angle_rows(device)[:d],
                    torch.tensor(s.clutter_rate, dtype=dtype, device=device), kappa, log_c,
                    SigmaPoints().weights(motion.dim_x, dtype, device), s, pair_h(model, dtype, device))


def check_lists(lists: AssociationLists, prior: Gaussian | None, n_pairs: int, n: int) -> None:
    """One-line errors for detections and priors (``None``: none, the tracker starts its own
    tracks) that do not fit."""
    B, K, L, M, _ = lists.z.shape
    if lists.candidates.shape[-1] != n_pairs:
        raise ConfigError(f"the detections name {lists.candidates.shape[-1]} illuminator pair(s); the measurement "
                          f"model has {n_pairs}")
    if bool(torch.isnan(lists.z[lists.valid]).any()) or bool(torch.isinf(lists.z).any()):
        raise ConfigError("a valid detection is NaN or infinite")
    if prior is None:
        return
    if prior.x.dim() != 3 or prior.x.shape[0] != B or prior.x.shape[-1] != n:
        raise ConfigError(f"prior must be x (B={B}, N, {n}); got {tuple(prior.x.shape)}")
    if not bool(torch.isfinite(prior.x).all()):
        raise ConfigError("the prior mean is not finite")
