"""S-MSJPDA, P-MSJPDA and the true-assignment reference (:mod:`pmsr_nn.trackers.msjpda`) on the
detections.

Option ``initiation`` says how S-/P-MSJPDA's tracks start:

* ``oracle`` (the paper's study, the default): at each target's birth from its initiation prior
  ("the true state plus some random noise"), one slot per target, associating only while the
  target lives. A reference row: the tracker is handed the births.
* ``detections``: the tracker starts, confirms and deletes its own tracks, with the track
  management of :mod:`.track_management` (its options are documented there); it returns
  unpaired tracks, scored as tracks. S-MSJPDA from detections can add the innovation bias test
  (``bias_window``; :mod:`pmsr_nn.trackers.innovation_bias`), which deletes a confirmed track
  whose innovations keep a mean (a formation's ghost).

P-MSJPDA ranks its (S+1)-D events by ``m_best_search``: ``branch_and_bound`` (the default, exact;
:mod:`pmsr_nn.trackers.assignment_bnb`) or ``relaxation`` (the paper's Lagrangian relaxation,
``relaxation_iterations`` per subproblem; its duality gap can hide cheaper events).

Extras of oracle-initiated rows (read by the kinds' metrics, :mod:`.kind_metrics`: the paper's
loss rule :class:`~.kind_metrics.TrackLoss` and :class:`~.kind_metrics.DualityGap`):
``dummy_most_probable (B, K, N)``, ``gate_range_sd_m (B, K, N)`` and, for P-MSJPDA,
``max_duality_gap`` (nats).
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from ..trackers.base import Estimates
from ..trackers.jpda import M_BEST_SEARCHES
from ..trackers.msjpda import JPDASettings, msjpda, true_assignment_ukf
from ..trackers.msjpda_managed import managed_msjpda
from . import MethodCall, MethodKind, Option, ReadWhen, register
from .kind_metrics import DualityGap, TrackLoss
from .track_management import BIAS_OPTIONS, MANAGEMENT_OPTIONS, check_initiation, clutter_density, management

ARCHITECTURE = {"s_msjpda": "sequential", "p_msjpda": "parallel"}


def settings(call: MethodCall) -> JPDASettings:
    """The JPDA settings of a call: the case's Pd and clutter density (:func:`clutter_density`)
    and the method's options."""
    s, spec = call.sensing, call.spec
    return JPDASettings(pd=s.pd, clutter_density=clutter_density(s), m_best=int(spec.option("m_best")),
                        gate_probability=float(spec.option("gate_probability")),
                        relaxation_iterations=int(spec.option("relaxation_iterations")),
                        m_best_search=str(spec.option("m_best_search")))


def _estimates(res, alive: torch.Tensor, gap: float | None) -> Estimates:
    B, K, N = res.dummy_most_probable.shape
    live = alive.expand(B, K, N)
    extras = {"dummy_most_probable": res.dummy_most_probable & live, "gate_range_sd_m": res.gate_range_sd_m}
    if gap is not None:
        extras["max_duality_gap"] = gap
    return Estimates(res.x, live, res.P, extras)


def run_msjpda(call: MethodCall) -> Estimates:
    m, s = call.models, call.sensing
    det = call.product
    R = s.detection_model.R(device=det.scans.z.device)
    if call.spec.option("initiation") == "detections":
        rep = managed_msjpda(det.scans, m.motion, m.dt, m.q, s.detection_model, R, settings(call),
                             ARCHITECTURE[call.spec.kind], management(call.spec, s))
        return Estimates(rep.x, rep.exists, rep.P, paired=False, existence=rep.existence)
    active = None if bool(call.alive.all()) else call.alive
    res = msjpda(det.scans, det.prior, m.motion, m.dt, m.q, s.detection_model, R, settings(call),
                 ARCHITECTURE[call.spec.kind], active=active)
    return _estimates(res, call.alive, res.max_duality_gap if call.spec.kind == "p_msjpda" else None)


def run_true_assignment(call: MethodCall) -> Estimates:
    m, s, det = call.models, call.sensing, call.product
    res = true_assignment_ukf(det.scans, det.prior, m.motion, m.dt, m.q, s.detection_model,
                              s.detection_model.R(device=det.scans.z.device))
    return _estimates(res, call.alive, None)


def _all_from_start(spec, alive: torch.Tensor, resource, case: str) -> None:
    if not bool(alive[0].all()):
        raise ConfigError(f"method {spec.name!r}: kind true_assignment starts every track at scan 0; case {case!r} "
                          "has targets born later")


OPTIONS = {"m_best": Option(10, int, 1, 100_000), "gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12),
           # P-MSJPDA's (S+1)-D events (S-MSJPDA's 2-D events are always exact)
           "relaxation_iterations": Option(20, int, 1, 10_000, read_when=ReadWhen("m_best_search", ("relaxation",))),
           "m_best_search": Option("branch_and_bound", str, choices=M_BEST_SEARCHES), **MANAGEMENT_OPTIONS,
           **BIAS_OPTIONS}  # the innovation bias test: S-MSJPDA from detections only
register(MethodKind("s_msjpda", "detections", run_msjpda, OPTIONS, check_sensing=check_initiation, metrics=(TrackLoss(),),
                    any_device=True, batchable=True,
                    description="sequential multi-sensor JPDA (Lyu & Wang, IEEE Access 2019), pair by pair; "
                                "initiation: oracle (handed the births) or detections (starts its own tracks)"))
register(MethodKind("p_msjpda", "detections", run_msjpda, OPTIONS, check_sensing=check_initiation,
                    metrics=(TrackLoss(), DualityGap()), any_device=True,
                    batchable=True,  # the gap of a joined call: its largest
                    description="parallel multi-sensor JPDA, (N+1)-D joint events (Lyu & Wang, IEEE Access 2019); "
                                "initiation: oracle or detections"))
register(MethodKind("true_assignment", "detections", run_true_assignment, {}, check=_all_from_start,
                    metrics=(TrackLoss(),), any_device=True, batchable=True,
                    description="reference: a UKF per target on exactly its own detections (true origins)"))
