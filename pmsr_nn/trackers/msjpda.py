"""Multi-sensor JPDA: sequential (S-MSJPDA) and parallel (P-MSJPDA), Lyu & Wang, IEEE Access 2019,
handed their targets' births, and the true-assignment reference.

Both are assemblies on the one tracker loop (:func:`~.loop.run_tracker`): the associator of
:mod:`.jpda_associators` (:class:`~.jpda_associators.SequentialJPDA`, pair by pair, Eqs. 15-21;
:class:`~.jpda_associators.ParallelJPDA`, (S+1)-D joint events, Eqs. 9-14) with the management
:class:`~.handed_births.HandedBirths` here (one track per target from its initiation prior, no
birth or death of tracks), or :class:`~.own_tracks.OwnTracks` in :mod:`.msjpda_managed`. Every
Monte Carlo run is tracked at once: the UKF moments, gates, likelihoods and mixture updates are
batched over runs and tracks; S-MSJPDA's m-best events are batched over the clusters of all
runs, P-MSJPDA's ranked cluster by cluster (an exact branch and bound, or the paper's Lagrangian
relaxation).

Missed detections at Pd = 1 keep a finite cost (``1 - Pd`` floored at 1e-300) so an event always
exists; with one track, one pair, no clutter and Pd = 1 both trackers are the UKF.

Per scan and track the trackers also record what the paper's loss rule reads: whether the
dummy (no detection) is the most probable association at every pair, and the predicted
bistatic-range deviation (the gate size).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.gaussian import Gaussian
from ..measurements import MeasurementModel
from ..motion import KinematicModel
from ..simulation.detections import Scans, check_model_for_detections
from .handed_births import HandedBirths, MultiTargetResult
from .jpda import M_BEST_SEARCHES
from .jpda_associators import Association, ParallelJPDA, SequentialJPDA
from .loop import run_tracker

__all__ = ["JPDASettings", "MultiTargetResult", "associator", "check_scans", "check_tracker_inputs", "check_variant",
           "msjpda", "true_assignment_ukf"]


@dataclass(frozen=True)
class JPDASettings:
    """``pd`` detection probability, ``clutter_density`` expected clutter per unit of measurement
    space (1 / (m Hz)), ``m_best`` events per cluster, ``gate_probability`` of the chi-square gate,
    and for P-MSJPDA's (N+1)-D events ``m_best_search`` (:data:`.jpda.M_BEST_SEARCHES`: exact
    branch and bound, or the paper's Lagrangian relaxation) and ``relaxation_iterations``."""

    pd: float
    clutter_density: float
    m_best: int = 10
    gate_probability: float = 0.999
    relaxation_iterations: int = 20
    m_best_search: str = "branch_and_bound"

    def __post_init__(self) -> None:
        require(0.0 < self.pd <= 1.0, f"pd must be in (0, 1], got {self.pd}")
        require(self.clutter_density > 0 and math.isfinite(self.clutter_density),
                f"clutter_density must be positive (a tracker needs a clutter model), got {self.clutter_density}")
        require(self.m_best >= 1, f"m_best must be at least 1, got {self.m_best}")
        require(self.relaxation_iterations >= 1, "relaxation_iterations must be at least 1")
        require(self.m_best_search in M_BEST_SEARCHES,
                f"m_best_search must be one of {', '.join(M_BEST_SEARCHES)}, got {self.m_best_search!r}")


def check_scans(scans: Scans, model: MeasurementModel) -> None:
    """One-line errors for detections ``model`` can not read (sensor count, values, NaN)."""
    check_model_for_detections(model)
    B, K, S, M = scans.shape
    if S != model.n_pairs or scans.z.shape[-1] != len(model.components):
        raise ConfigError(f"detections are from {S} sensors with {scans.z.shape[-1]} values each; the model has "
                          f"{model.n_pairs} sensors with {len(model.components)}")
    if bool(torch.isnan(scans.z[scans.valid]).any()) or bool(torch.isinf(scans.z).any()):
        raise ConfigError("a valid detection is NaN or infinite")


def check_tracker_inputs(scans: Scans, prior: Gaussian, motion: KinematicModel, model: MeasurementModel) -> None:
    """:func:`check_scans`, and the initiation prior ``x (B, N, n)``, ``P (B, N, n, n)`` of ``N`` targets."""
    check_scans(scans, model)
    B = scans.shape[0]
    n = motion.dim_x
    if prior.x.dim() != 3 or prior.x.shape[0] != B or prior.x.shape[-1] != n or prior.P.shape != (*prior.x.shape, n):
        raise ConfigError(f"prior must be x (B={B}, N, {n}) and P (B, N, {n}, {n}); got {tuple(prior.x.shape)}, "
                          f"{tuple(prior.P.shape)}")
    if not bool(torch.isfinite(prior.x).all()):
        raise ConfigError("the prior mean is not finite")


def check_variant(architecture: str, association: str) -> None:
    """One-line refusals of an architecture / association mix no associator offers."""
    if architecture not in ("sequential", "parallel"):
        raise ConfigError(f"architecture must be 'sequential' or 'parallel', got {architecture!r}")
    if association not in ("jpda", "pda"):
        raise ConfigError(f"association must be 'jpda' or 'pda', got {association!r}")
    if architecture == "parallel" and association != "jpda":
        raise ConfigError("P-MSJPDA associates jointly over the sensors: no pda association")


def msjpda(scans: Scans, prior: Gaussian, motion: KinematicModel, dt: float, q: float, model: MeasurementModel,
           R: torch.Tensor, settings: JPDASettings, architecture: Literal["sequential", "parallel"],
           active: torch.Tensor | None = None, association: Association = "jpda") -> MultiTargetResult:
    """Track ``N`` targets through ``scans`` (``B`` runs, ``K`` scans) from ``prior`` ``x (B, N, n)``.

    Step 0 is an update of the prior only (the convention of :mod:`pmsr_nn.filters.kalman`); every
    later scan a CV/CA prediction over ``dt`` with process noise ``q``, then the update of the
    chosen architecture. ``R (S d, S d)`` is block-diagonal over the ``S`` pairs (pair layout).

    ``active (K, N)`` or ``(B, K, N)`` (default: every track at every scan) gives each track's
    life: a track is started from its ``prior`` at its first active scan (the prior is then the
    state at that scan), takes part in the association only while active, and is only predicted
    otherwise (its estimates there mean nothing).

    ``association`` (sequential only): see :func:`~.jpda_associators.pair_update`.
    """
    check_tracker_inputs(scans, prior, motion, model)
    check_variant(architecture, association)
    return run_tracker(scans, motion, dt, q, associator(model, R, settings, architecture, association),
                       HandedBirths(prior, active))


def associator(model: MeasurementModel, R: torch.Tensor, settings: JPDASettings,
               architecture: Literal["sequential", "parallel"],
               association: Association = "jpda") -> SequentialJPDA | ParallelJPDA:
    """The associator of S-MSJPDA (``sequential``) or P-MSJPDA (``parallel``)."""
    if architecture == "sequential":
        return SequentialJPDA(model, R, settings, association)
    return ParallelJPDA(model, R, settings)


def true_assignment_ukf(scans: Scans, prior: Gaussian, motion: KinematicModel, dt: float, q: float,
                        model: MeasurementModel, R: torch.Tensor) -> MultiTargetResult:
    """The reference of Fig. 3: each track is updated by a UKF with exactly the detections its
    target caused (the truth origin), none when missed, and never with clutter."""
    from ..filters import ukf

    check_tracker_inputs(scans, prior, motion, model)
    B, K, S, M = scans.shape
    N, n = prior.x.shape[1:]
    z = scans.target_measurements(N).permute(0, 2, 1, 3, 4).reshape(B * N, K, -1)  # pair layout
    r = ukf(Gaussian(prior.x.reshape(B * N, n), prior.P.reshape(B * N, n, n)), z, motion, dt, q, model, R)
    x = r.x.reshape(B, N, K, n).transpose(1, 2)
    P = r.P.reshape(B, N, K, n, n).transpose(1, 2)
    d = len(model.components)
    missed = torch.isnan(z.reshape(B, N, K, S, d)[..., 0]).all(-1).transpose(1, 2)
    no_gate = x.new_zeros(B, K, N)  # the reference has no gate, so the gate rule never fires
    return MultiTargetResult(x, P, missed, no_gate)
