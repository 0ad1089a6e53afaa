"""Neural-enhanced belief propagation on the detections, ``kind: nebp``: the BP tracker of ``kind:
bp`` (:mod:`.bp`, every option its own) with the learned corrections of
:mod:`pmsr_nn.trackers.message_refiner` (Liang & Meyer, IEEE TSP 2024), from a checkpoint of
``pmsr train`` with a ``kind: nebp`` config (``train/nebp.yaml``).

It reads the per-pair lists (the illuminator given), as ``bp`` does. The checkpoint must have been
trained for the scenario's sensors: its pair count, measurement components and deviations,
geometry, interval and state size (one-line refusal otherwise, before anything is written).
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from ..trackers.base import Estimates
from ..trackers.bp_tracker import bp_tracker
from ..trackers.message_refiner import MessageRefiner
from . import MethodCall, MethodKind, register
from .bp import OPTIONS, check_sensing, settings


def _load(spec, context):
    """The checkpoint, checked against the scenario's sensors before anything is written."""
    from ..nets.nebp import check_nebp_compatible, load_nebp_checkpoint

    where = f"method {spec.name!r}"
    det = context.detection_model
    if det is None:
        raise ConfigError(f"{where}: kind nebp reads detections; the scenario makes none (add a detections section)")
    ck = load_nebp_checkpoint(context.path(spec.checkpoint))
    check_nebp_compatible(ck, context.geometry, det.n_pairs, det.components, det.noise_std, context.dt,
                          ck.meta["dim_x"], where)
    device = torch.device(context.device)
    if device.type != "cpu":  # the network and its scales where the tracks will be
        ck.net.to(device)
        ck.scales = ck.scales.to(device)
    return ck


def run_nebp(call: MethodCall) -> Estimates:
    m, s, det, ck = call.models, call.sensing, call.product, call.resource
    if m.motion.dim_x != ck.meta["dim_x"]:
        raise ConfigError(f"method {call.spec.name!r}: the checkpoint's state has {ck.meta['dim_x']} entries, the "
                          f"scenario's {m.motion.dim_x}")
    model = s.detection_model
    scans = det.scans
    refiner = MessageRefiner(ck.net, model.components, model.n_pairs, ck.scales, float(model.noise_std[0]))
    with torch.no_grad():
        rep = bp_tracker(scans, m.motion, m.dt, m.q, model, model.R(device=scans.z.device), settings(call.spec, s),
                         s.prior_sd, float(call.spec.option("birth_velocity_sd_mps")), refiner=refiner)
    return Estimates(rep.x, rep.exists, rep.P, paired=False, existence=rep.existence)


def _check(spec, sensing) -> None:
    """kind bp's checks, and azimuth: NEBP's new targets are seeded from single detections."""
    check_sensing(spec, sensing)
    if "azimuth" not in sensing.detection_model.components:
        raise ConfigError(f"method {spec.name!r}: kind nebp seeds its new targets from single detections and needs "
                          "azimuth in the detections (use kind bp without azimuth)")


register(MethodKind("nebp", "detections", run_nebp, OPTIONS, needs_checkpoint=True, load=_load, check_sensing=_check,
                    starts_tracks=True, any_device=True, batchable=True,
                    description="neural-enhanced belief propagation (Liang & Meyer, IEEE TSP 2024): the BP tracker "
                                "with learned corrections of its association likelihoods and of each detection's weight of "
                                "target against clutter (pmsr train train/nebp.yaml)"))
