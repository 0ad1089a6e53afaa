"""S-MSJPDA, P-MSJPDA and the true-assignment reference (:mod:`pmsr_nn.trackers.msjpda`) on the
detections. Tracks are started at each target's birth from its initiation prior (the paper:
"the true state plus some random noise") and associate only while the target lives.

Extras (read by the paper's loss rule and the report): ``dummy_most_probable (B, K, N)``,
``gate_range_sd_m (B, K, N)`` and, for P-MSJPDA, ``max_duality_gap`` (nats).
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from ..trackers.base import Estimates
from ..trackers.msjpda import JPDASettings, msjpda, true_assignment_ukf
from . import MethodCall, MethodKind, Option, register

ARCHITECTURE = {"s_msjpda": "sequential", "p_msjpda": "parallel"}


def clutter_density(s) -> float:
    """Expected clutter per unit of one pair's measurement space (``SensorSetup`` ``s``), floored:
    a tracker needs a positive clutter density even where none was simulated."""
    components = s.detection_model.components
    clutter = s.pair_clutter()  # the clutter of each pair's list
    return max(clutter.density_of(components), 1e-3 / clutter.volume_of(components))


def settings(call: MethodCall) -> JPDASettings:
    """The JPDA settings of a call: the case's Pd and clutter density (:func:`clutter_density`)
    and the method's options."""
    s, spec = call.sensing, call.spec
    return JPDASettings(pd=s.pd, clutter_density=clutter_density(s), m_best=int(spec.option("m_best")),
                        gate_probability=float(spec.option("gate_probability")),
                        relaxation_iterations=int(spec.option("relaxation_iterations")))


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


OPTIONS = {"m_best": Option(10, int, 1, 100_000), "gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12),
           "relaxation_iterations": Option(20, int, 1, 10_000)}
register(MethodKind("s_msjpda", "detections", run_msjpda, OPTIONS, multi_target=True,
                    description="sequential multi-sensor JPDA (Lyu & Wang 2019)"))
register(MethodKind("p_msjpda", "detections", run_msjpda, OPTIONS, multi_target=True,
                    description="parallel multi-sensor JPDA with (N+1)-D assignment (Lyu & Wang 2019)"))
register(MethodKind("true_assignment", "detections", run_true_assignment, {}, check=_all_from_start,
                    multi_target=True, description="UKF per target on exactly its own detections"))
