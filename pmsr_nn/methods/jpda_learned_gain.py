"""The hybrid tracker on detections: S-MSJPDA with a learned gain correction
(:mod:`pmsr_nn.trackers.learned_gain`), from a checkpoint of ``pmsr train`` with a
``kind: jpda_gain`` config (``train/jpda_gain.yaml``).

Everything but the gain is S-MSJPDA's, options included: the JPDA settings, and ``initiation``
``oracle`` (handed each target's birth, a reference row) or ``detections`` (the shared track
management). ``association: pda`` treats each track on its own (no joint events; faster, but
tracks that share detections coalesce). ``memory``: ``training_window`` (default) clears a
track's learned memory every training window's worth of scans (the checkpoint's
``scenes.window``: the memory never runs longer than in training), ``unbounded`` never. A
checkpoint trained with ``learned_on: confirmed`` corrects the confirmed tracks only (tentative
ones run on the model's gain), as in its training. ``bias_window`` (with ``initiation:
detections``) adds S-MSJPDA's innovation bias test (:mod:`pmsr_nn.trackers.innovation_bias`);
``bias_action: learn`` makes the learned correction act on the tracks it flags only (the rest
run on the model's gain), ``delete`` deletes them as S-MSJPDA does.
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from ..trackers.base import Estimates
from ..trackers.gating import gate_threshold
from ..trackers.learned_gain import GainCorrection
from ..trackers.msjpda import msjpda
from ..trackers.msjpda_managed import managed_msjpda
from . import MethodCall, MethodKind, Option, ReadWhen, register
from .msjpda import OPTIONS, settings
from .track_management import check_initiation, management


def _load(spec, context):
    """The checkpoint, checked against the scenario's sensors before anything is written."""
    from ..nets.jpda_gain import check_gain_compatible, load_gain_checkpoint

    where = f"method {spec.name!r}"
    det = context.detection_model
    if det is None:
        raise ConfigError(f"{where}: kind jpda_learned_gain reads detections; the scenario makes none "
                          "(add a detections section)")
    ck = load_gain_checkpoint(context.path(spec.checkpoint))
    check_gain_compatible(ck, context.geometry, det.components, det.noise_std, context.dt, len(ck.s_x), where)
    device = torch.device(context.device)
    if device.type != "cpu":  # the network and its scales where the tracks will be
        ck.net.to(device)
        ck.s_z, ck.s_x = ck.s_z.to(device), ck.s_x.to(device)
    return ck


def run_learned_gain(call: MethodCall) -> Estimates:
    m, s, det, ck = call.models, call.sensing, call.product, call.resource
    if m.motion.dim_x != len(ck.s_x):
        raise ConfigError(f"method {call.spec.name!r}: the checkpoint's state has {len(ck.s_x)} entries, the "
                          f"scenario's {m.motion.dim_x}")
    window = ck.meta.get("training", {}).get("config", {}).get("scenes", {}).get("window")
    horizon = None if call.spec.option("memory") == "unbounded" or not isinstance(window, int) else \
        window * s.detection_model.n_pairs
    p = call.spec.option("consistency_probability")
    consistency = None if p is None else gate_threshold(float(p), len(s.detection_model.components))
    training = ck.meta.get("training", {}).get("config", {})
    corr = GainCorrection(ck.net, ck.s_z, ck.s_x, horizon, consistency, training.get("learned_on") == "confirmed")
    assoc = call.spec.option("association")
    R = s.detection_model.R(device=det.scans.z.device)
    with torch.no_grad():
        if call.spec.option("initiation") == "detections":
            rep = managed_msjpda(det.scans, m.motion, m.dt, m.q, s.detection_model, R, settings(call), "sequential",
                                 management(call.spec, s), assoc, corr)
            return Estimates(rep.x, rep.exists, rep.P, paired=False, existence=rep.existence)
        active = None if bool(call.alive.all()) else call.alive
        res = msjpda(det.scans, det.prior, m.motion, m.dt, m.q, s.detection_model, R, settings(call), "sequential",
                     active, assoc, corr)
    B, K, N = res.dummy_most_probable.shape
    return Estimates(res.x, call.alive.expand(B, K, N), res.P)


register(MethodKind("jpda_learned_gain", "detections", run_learned_gain,
                    {**OPTIONS, "association": Option("jpda", str, choices=("jpda", "pda")),
                     "memory": Option("training_window", str, choices=("training_window", "unbounded")),
                     "bias_action": Option("delete", str, choices=("delete", "learn"), read_when=ReadWhen("bias_window")),
                     "consistency_probability": Option(0.99, float, 0.5, 1.0 - 1e-12, nullable=True,
                                                       null="the learned gain acts at every step")},
                    needs_checkpoint=True, load=_load, check_sensing=check_initiation, any_device=True,
                    description="S-MSJPDA with a learned correction of its gain (pmsr train train/jpda_gain.yaml); "
                                "initiation: oracle or detections"))
