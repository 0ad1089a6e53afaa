"""PMHT (:mod:`pmsr_nn.trackers.pmht`) on the detections, and the true-assignment smoother.

* ``pmht``: the standard PMHT, given each detection's illuminator (the per-pair lists, also when
  the scenario pools them per receiver: it is then a reference that knows more than a
  single-frequency network tells);
* ``pmht_3d``: the target-detection-illuminator PMHT (Li et al., JEIT 2021) on the lists a
  receiver really has: per receiver, illuminator unknown, where the scenario's
  ``illuminator_known`` is false; on per-pair lists otherwise (where it is the standard PMHT
  with the measurement mixture);
* ``true_assignment_smoother``: a UKF and RTS smoother per target on exactly its own detections,
  the floor of what any association can reach with the same smoother.

Option ``initiation`` of ``pmht`` and ``pmht_3d`` says how tracks start (as for S-/P-MSJPDA,
:mod:`.msjpda`, with the same track-management options):

* ``oracle`` (the default): at scan 0 from the initiation prior (truth at scan 0 plus a draw from
  ``N(0, P0)``), lasting the whole scenario; a case with births or deaths is refused;
* ``detections``: the tracker starts, confirms and deletes its own tracks
  (:func:`~pmsr_nn.trackers.pmht_managed.managed_pmht`) and returns unpaired tracks, scored as tracks.
  ``pmht_3d`` does so on the lists a single-frequency-network receiver has (pooled, the
  illuminator unknown): each unused detection is fixed under every illuminator hypothesis
  (:class:`~pmsr_nn.trackers.fix_initiator.FixInitiator`, 3 pairs by default there), so the
  pairs must measure azimuth.

The association priors are fixed from the case's Pd and clutter.
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from ..filters.smoothing import rts_backward
from ..trackers.base import Estimates
from ..trackers.msjpda import true_assignment_ukf
from ..trackers.pmht import pmht
from ..trackers.pmht_managed import managed_pmht
from ..trackers.pmht_model import E_STEPS, AssociationLists, PMHTSettings
from . import MIN_CLUTTER_PER_SCAN, MethodCall, MethodKind, Option, register
from .track_management import MANAGEMENT_OPTIONS, check_initiation, management


def settings(call: MethodCall) -> PMHTSettings:
    """The PMHT settings of a call: the case's Pd and per-pair clutter rate, the method's options."""
    s, spec = call.sensing, call.spec
    clutter = s.pair_clutter()
    rate = max(clutter.per_scan, MIN_CLUTTER_PER_SCAN)
    wide = spec.kind == "pmht_3d" and float(spec.option("wide_weight")) > 0
    return PMHTSettings(
        pd=s.pd, clutter_rate=(rate,) * s.detection_model.n_pairs, volume=clutter.volume_of(s.detection_model.components),
        window=int(spec.option("window")), overlap=int(spec.option("overlap")),
        em_iterations=int(spec.option("em_iterations")), tolerance_m=float(spec.option("tolerance_m")),
        anneal=float(spec.option("anneal")), e_step=str(spec.option("e_step")),
        kappa=(1.0, float(spec.option("wide_kappa"))) if wide else (1.0,),
        kappa_weights=(1.0 - float(spec.option("wide_weight")), float(spec.option("wide_weight"))) if wide else None)


def lists_of(call: MethodCall) -> AssociationLists:
    det = call.product
    if call.spec.kind == "pmht_3d" and det.pooled is not None:
        return AssociationLists.pooled(det.pooled)
    return AssociationLists.per_pair(det.scans)


def run_pmht(call: MethodCall) -> Estimates:
    m, s = call.models, call.sensing
    R = s.detection_model.R(device=call.product.scans.z.device)
    if call.spec.option("initiation") == "detections":
        pooled = call.spec.kind == "pmht_3d" and call.product.pooled is not None
        rep = managed_pmht(call.product.pooled if pooled else call.product.scans, m.motion, m.dt, m.q, s.detection_model,
                           R, settings(call), management(call.spec, s, pooled))
        return Estimates(rep.x, rep.exists, rep.P, paired=False, existence=rep.existence)
    res = pmht(lists_of(call), call.product.prior, m.motion, m.dt, m.q, s.detection_model, R, settings(call))
    B, K, N = res.x.shape[:3]
    return Estimates(res.x, torch.ones(B, K, N, dtype=torch.bool, device=res.x.device), res.P)


def run_true_assignment_smoother(call: MethodCall) -> Estimates:
    m, s, det = call.models, call.sensing, call.product
    dev = det.scans.z.device
    R = s.detection_model.R(device=dev)
    res = true_assignment_ukf(det.scans, det.prior, m.motion, m.dt, m.q, s.detection_model, R)
    B, K, N, n = res.x.shape
    rows = lambda t: t.transpose(1, 2).reshape(B * N, K, *t.shape[3:])
    sm = rts_backward(rows(res.x), rows(res.P), m.motion.F(m.dt, device=dev), m.motion.Q(m.dt, m.q, device=dev))
    back = lambda t: t.reshape(B, N, K, *t.shape[2:]).transpose(1, 2)
    return Estimates(back(sm.x), call.alive.expand(B, K, N), back(sm.P))


def _check_pmht(spec, alive: torch.Tensor, resource, case: str) -> None:
    K = alive.shape[0]
    window, overlap = int(spec.option("window")), int(spec.option("overlap"))
    if window > K:
        raise ConfigError(f"method {spec.name!r}: window of {window} scans is longer than case {case!r} ({K} scans)")
    if overlap >= window:
        raise ConfigError(f"method {spec.name!r}: overlap {overlap} must be smaller than the window ({window})")
    if spec.option("initiation") == "oracle":  # tracks that start and end themselves follow births and deaths
        _all_throughout(spec, alive, resource, case)


def _check_sensing(spec, sensing) -> None:
    """Track management that could never confirm a track, detections no initiator can read
    (for ``pmht_3d`` on lists pooled per receiver: pairs without azimuth)."""
    check_initiation(spec, sensing, pooled=spec.kind == "pmht_3d" and not sensing.illuminator_known)


def _all_throughout(spec, alive: torch.Tensor, resource, case: str) -> None:
    if not bool(alive.all()):
        raise ConfigError(f"method {spec.name!r}: kind {spec.kind} keeps every track from scan 0 to the end; case "
                          f"{case!r} has targets born later or dying earlier")


OPTIONS = {"window": Option(10, int, 1, 100_000), "overlap": Option(3, int, 0, 99_999),
           "em_iterations": Option(6, int, 1, 1000), "tolerance_m": Option(0.0, float, 0.0, 1e6),
           "anneal": Option(1.0, float, 1.0, 1e6), "e_step": Option("point", str, choices=E_STEPS),
           **MANAGEMENT_OPTIONS}
OPTIONS_3D = {**OPTIONS, "wide_kappa": Option(4.0, float, 1.0, 1e4), "wide_weight": Option(0.5, float, 0.0, 0.99)}
register(MethodKind("pmht", "detections", run_pmht, OPTIONS, causal=lambda r: False, check=_check_pmht,
                    check_sensing=_check_sensing, any_device=True,
                    description="PMHT with an unscented smoother, illuminator of each detection given "
                                "(Streit & Luginbuhl 1995); smoothed, not causal; initiation: oracle or detections"))
register(MethodKind("pmht_3d", "detections", run_pmht, OPTIONS_3D, causal=lambda r: False, check=_check_pmht,
                    check_sensing=_check_sensing, pooled_lists=True, any_device=True,
                    description="target-detection-illuminator PMHT with a Gaussian scale mixture "
                                "(Li et al., JEIT 2021): per receiver, illuminator unknown; initiation: oracle or "
                                "detections (also from the pooled lists)"))
register(MethodKind("true_assignment_smoother", "detections", run_true_assignment_smoother, {},
                    causal=lambda r: False, check=_all_throughout, any_device=True,
                    description="reference: a UKF + RTS smoother per target on exactly its own detections"))
