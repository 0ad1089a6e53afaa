"""S-/P-MSJPDA that start, confirm and delete their own tracks (:mod:`.management`), with the
hybrid's learned gain correction (:mod:`.learned_gain`) and the innovation bias test
(:mod:`.innovation_bias`) where asked for. The association and update steps are
:mod:`.msjpda`'s, shared with the trackers handed their births."""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch

from ..errors import ConfigError
from ..filters.gaussian import predict
from ..measurements import MeasurementModel
from ..motion import KinematicModel
from ..simulation.detections import Scans
from .gating import gate_threshold
from .innovation_bias import BiasTest
from .learned_gain import Association, GainCorrection
from .management import Management, TrackReport, TrackTable, parked_state
from .msjpda import JPDASettings, _check_variant, _joint_step, _sensor_step, check_scans


def _learned_tracks(table: TrackTable, correction: GainCorrection | None, bias: BiasTest | None) -> torch.Tensor | None:
    """Where a hybrid's learned correction acts this scan (None: every active track): the tracks
    the bias test flagged with action ``learn``, else the confirmed ones for a correction trained
    on them only."""
    if correction is None:
        return None
    if bias is not None and bias.action == "learn":
        return table.biased(bias)
    return table.confirmed if correction.confirmed_only else None


def managed_msjpda(scans: Scans, motion: KinematicModel, dt: float, q: float, model: MeasurementModel, R: torch.Tensor,
                   settings: JPDASettings, architecture: Literal["sequential", "parallel"],
                   management: Management, association: Association = "jpda",
                   correction: GainCorrection | None = None) -> TrackReport:
    """S-/P-MSJPDA that start, confirm and delete their own tracks (:mod:`.management`).

    Every scan: predict the table's tracks, associate and update them as :func:`msjpda` does
    (tentative and confirmed tracks alike) and update their existence probabilities (IPDA:
    each pair's gated detections against clutter), count at how many pairs each was detected,
    confirm and delete, then start tentative tracks from the detections no track gated. Step 0
    has no prediction. Returns the confirmed tracks as reported at each scan (those whose
    existence is at least the management's ``report_existence``).

    ``association`` and ``correction`` (sequential only): see :func:`_sensor_step`; a slot's
    learned memory is cleared when its track is deleted.
    """
    check_scans(scans, model)
    _check_variant(architecture, association, correction)
    bias = management.bias
    if bias is not None and (architecture == "parallel" or (bias.action == "learn" and correction is None)):
        raise ConfigError("the innovation bias test reads per-pair innovations (sequential MSJPDA only); its action "
                          "'learn' needs a learned gain correction")
    B, K, N, M = scans.shape
    management.check(model, f"{architecture} MSJPDA")
    n, dtype = motion.dim_x, scans.z.dtype
    gamma = gate_threshold(settings.gate_probability, len(model.components))
    F, Q = motion.F(dt, dtype), motion.Q(dt, q, dtype)
    subs = [model.for_pairs([k]) for k in range(N)]
    rows = [model.rows_for_pairs([k]) for k in range(N)]
    table = TrackTable.empty(B, n, parked_state(model, n, dtype))
    report = TrackReport.empty(B, K, n, dtype)
    pos = list(motion.pos_idx)
    if correction is not None:
        correction.start(B, table.g.x.shape[1])
    for k in range(K):
        if k > 0:
            table.g = predict(table.g, F, Q)
            table.free(~table.active)  # keep free slots parked
            table.predict_existence(management.survival)
        act = table.active
        learned = _learned_tracks(table, correction, management.bias)
        used = np.zeros((B, N, M), dtype=bool)
        pd_pg = settings.pd * settings.gate_probability
        if architecture == "sequential":
            detected = torch.zeros(act.shape, dtype=torch.int64)
            for j in range(N):
                table.g, missed, _, gated, ratio, e_c = _sensor_step(
                    table.g, scans.z[:, k, j], scans.valid[:, k, j], subs[j], R[rows[j]][:, rows[j]], settings, gamma,
                    act, association, correction, j, learned)
                detected += torch.from_numpy(~missed) & act
                used[:, j] = gated.any(1)
                table.update_existence(ratio, pd_pg)
                if management.bias is not None:
                    table.update_bias(management.bias, j, N, e_c)
        else:
            table.g, _, _, _, gated, det, ratio = _joint_step(table.g, scans.z[:, k], scans.valid[:, k], model, R,
                                                              settings, gamma, act)
            detected = torch.from_numpy(det)
            used = gated.any(1)
            for j in range(N):
                table.update_existence(ratio[..., j], pd_pg)
        table.record(detected, management.hit_pairs)
        table.manage(management.confirmer, management.deleter, pos, management.bias)
        if correction is not None:
            correction.forget(~table.active)
        unused = scans.valid[:, k] & ~torch.from_numpy(used)
        if bool(unused.any()):
            table.add(*management.initiator.initiate(scans.z[:, k], unused, model, n, management.other_sd),
                      management.initial_existence)
        report.write(k, table, management.report_existence)
    return report.trimmed()
