"""S-MSJPDA, P-MSJPDA and the true-assignment reference (:mod:`pmsr_nn.trackers.msjpda`) on the
detections.

Option ``initiation`` says how S-/P-MSJPDA's tracks start:

* ``oracle`` (the paper's study, the default): at each target's birth from its initiation prior
  ("the true state plus some random noise"), one slot per target, associating only while the
  target lives. A reference row: the tracker is handed the births.
* ``detections``: the tracker starts, confirms and deletes its own tracks with the shared
  components of :mod:`pmsr_nn.trackers.management` (an initiator, M-of-N confirmation, a deleter
  on misses); it returns unpaired tracks, scored as tracks. The initiator follows what the
  detections measure: with azimuth, the fix initiator (each pair's (range, azimuth) fixes a
  position; fixes of ``init_pairs`` pairs that agree start a track); with range and range-rate
  (or Doppler) but no azimuth, the spherical initiator (every combination of one detection per
  pair, at 3 or 4 pairs that share one transmitter or one receiver, whose joint fit of ranges
  and rates passes the gate). S-MSJPDA from detections can add the innovation bias test
  (``bias_window``, ``bias_probability``, ``bias_burn_in``; :mod:`pmsr_nn.trackers.innovation_bias`),
  which deletes a confirmed track whose innovations keep a mean (a formation's ghost).

P-MSJPDA ranks its (N+1)-D events by ``m_best_search``: ``branch_and_bound`` (the default, exact;
:mod:`pmsr_nn.trackers.assignment_bnb`) or ``relaxation`` (the paper's Lagrangian relaxation,
``relaxation_iterations`` per subproblem; its duality gap can hide cheaper events).

Extras of oracle-initiated rows (read by the paper's loss rule and the report):
``dummy_most_probable (B, K, N)``, ``gate_range_sd_m (B, K, N)`` and, for P-MSJPDA,
``max_duality_gap`` (nats).
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from ..trackers.base import Estimates
from ..trackers.fix_initiator import FixInitiator
from ..trackers.spherical_initiator import SphericalInitiator
from ..trackers.management import BiasTest, Confirmer, Deleter, Management
from ..trackers.jpda import M_BEST_SEARCHES, floored_clutter_density
from ..trackers.msjpda import JPDASettings, msjpda, true_assignment_ukf
from ..trackers.msjpda_managed import managed_msjpda
from . import MethodCall, MethodKind, Option, method_kind, register

ARCHITECTURE = {"s_msjpda": "sequential", "p_msjpda": "parallel"}


def clutter_density(s) -> float:
    """Expected clutter per unit of one pair's measurement space (``SensorSetup`` ``s``), floored:
    a tracker needs a positive clutter density even where none was simulated."""
    return floored_clutter_density(s.pair_clutter(), s.detection_model.components)  # the clutter of each pair's list


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


def bias_test(spec) -> BiasTest | None:
    """The innovation bias test a JPDA row's options ask for (``bias_window`` null: none)."""
    options = method_kind(spec.kind).options
    if "bias_window" not in options or spec.option("bias_window") is None:
        return None
    action = spec.option("bias_action") if "bias_action" in options else "delete"
    return BiasTest(float(spec.option("bias_window")), float(spec.option("bias_probability")), action,
                    int(spec.option("bias_burn_in")))


def management(spec, sensing, pooled: bool = False) -> Management:
    """The track-management components a method's options describe (``initiation: detections``).

    The initiator follows the detection model: azimuth among its components, the
    :class:`FixInitiator` (``init_pairs`` null: 2 pairs, 3 for a method that reads lists pooled
    per receiver, ``pooled``: every detection there is fixed under each transmitter, so two
    pairs agree by chance far more often, and a track started between two drones in formation
    lives on beside theirs); otherwise the :class:`SphericalInitiator` (range and range-rate or
    Doppler; ``init_pairs`` null: every pair), whose :meth:`~SphericalInitiator.check` refuses
    what neither can start tracks from."""
    o = spec.option
    pairs = o("init_pairs")
    velocity_sd, gate = float(o("birth_velocity_sd_mps")), float(o("init_gate_probability"))
    if "azimuth" in sensing.detection_model.components:
        initiator = FixInitiator(velocity_sd, (3 if pooled else 2) if pairs is None else int(pairs), gate)
    else:
        initiator = SphericalInitiator(velocity_sd, None if pairs is None else int(pairs), gate)
    return Management(initiator, Confirmer(int(o("confirm_m")), int(o("confirm_n"))), Deleter(int(o("delete_misses"))),
                      sensing.prior_sd, int(o("hit_pairs")), float(o("survival")), float(o("initial_existence")),
                      float(o("report_existence")), bias_test(spec))


def run_msjpda(call: MethodCall) -> Estimates:
    m, s = call.models, call.sensing
    det = call.product
    if call.spec.option("initiation") == "detections":
        rep = managed_msjpda(det.scans, m.motion, m.dt, m.q, s.detection_model, s.detection_model.R(), settings(call),
                             ARCHITECTURE[call.spec.kind], management(call.spec, s))
        return Estimates(rep.x, rep.exists, rep.P, paired=False, existence=rep.existence)
    active = None if bool(call.alive.all()) else call.alive
    res = msjpda(det.scans, det.prior, m.motion, m.dt, m.q, s.detection_model, s.detection_model.R(), settings(call),
                 ARCHITECTURE[call.spec.kind], active=active)
    return _estimates(res, call.alive, res.max_duality_gap if call.spec.kind == "p_msjpda" else None)


def run_true_assignment(call: MethodCall) -> Estimates:
    m, s, det = call.models, call.sensing, call.product
    res = true_assignment_ukf(det.scans, det.prior, m.motion, m.dt, m.q, s.detection_model, s.detection_model.R())
    return _estimates(res, call.alive, None)


def _all_from_start(spec, alive: torch.Tensor, resource, case: str) -> None:
    if not bool(alive[0].all()):
        raise ConfigError(f"method {spec.name!r}: kind true_assignment starts every track at scan 0; case {case!r} "
                          "has targets born later")


def check_initiation(spec, sensing, pooled: bool = False) -> None:
    """Track management that could never confirm a track, or detections neither initiator can
    start tracks from (``initiation: detections`` only; see :func:`management`; ``pooled``: the
    method reads lists pooled per receiver)."""
    if bias_test(spec) is not None and (spec.option("initiation") != "detections" or spec.kind == "p_msjpda"):
        raise ConfigError(f"method {spec.name!r}: the innovation bias test (bias_window) acts on the tracks a sequential "
                          f"tracker starts itself: set initiation: detections on s_msjpda or jpda_learned_gain, or "
                          f"bias_window: null")
    if spec.option("initiation") != "detections":
        return
    try:
        management(spec, sensing, pooled).check(sensing.detection_model, "initiation from detections", pooled=pooled)
    except ConfigError as exc:
        raise ConfigError(f"method {spec.name!r}: {exc}") from None


INITIATIONS = ("oracle", "detections")
# how tracks start and, with initiation: detections, the track management (pmsr_nn.trackers.management):
# shared by every kind that offers initiation from detections (with :func:`management` and :func:`check_initiation`)
MANAGEMENT_OPTIONS = {"initiation": Option("oracle", str, choices=INITIATIONS),
                      "init_pairs": Option(None, int, 1, 64, nullable=True,
                                           null="2 with azimuth (fix initiator; 3 from lists pooled per receiver), else every pair "
                                                "(spherical initiator)"),
                      "init_gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12),
                      "birth_velocity_sd_mps": Option(20.0, float, 1e-3, 1e5),
                      "confirm_m": Option(2, int, 1, 62), "confirm_n": Option(3, int, 1, 62),
                      "hit_pairs": Option(2, int, 1, 64), "delete_misses": Option(2, int, 0, 10_000),
                      "survival": Option(0.99, float, 1e-6, 1.0), "initial_existence": Option(0.5, float, 1e-6, 1.0),
                      "report_existence": Option(0.5, float, 0.0, 1.0)}
OPTIONS = {"m_best": Option(10, int, 1, 100_000), "gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12),
           # P-MSJPDA's (N+1)-D events (S-MSJPDA's 2-D events are always exact)
           "relaxation_iterations": Option(20, int, 1, 10_000),
           "m_best_search": Option("branch_and_bound", str, choices=M_BEST_SEARCHES), **MANAGEMENT_OPTIONS,
           # the innovation bias test (trackers/innovation_bias.py): S-MSJPDA from detections only
           "bias_window": Option(None, float, 1.0, 1e4, nullable=True, null="no innovation bias test"),
           "bias_probability": Option(0.999, float, 0.5, 1.0 - 1e-12),
           "bias_burn_in": Option(10, int, 0, 10_000)}
register(MethodKind("s_msjpda", "detections", run_msjpda, OPTIONS, check_sensing=check_initiation,
                    description="sequential multi-sensor JPDA (Lyu & Wang, IEEE Access 2019), pair by pair; "
                                "initiation: oracle (handed the births) or detections (starts its own tracks)"))
register(MethodKind("p_msjpda", "detections", run_msjpda, OPTIONS, check_sensing=check_initiation,
                    description="parallel multi-sensor JPDA, (N+1)-D joint events (Lyu & Wang, IEEE Access 2019); "
                                "initiation: oracle or detections"))
register(MethodKind("true_assignment", "detections", run_true_assignment, {}, check=_all_from_start,
                    description="reference: a UKF per target on exactly its own detections (true origins)"))
