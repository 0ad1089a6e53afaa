"""A tracker that starts, confirms and deletes its own tracks: the :class:`~.roles.TrackManagement`
of :func:`~.loop.run_tracker` built from the components of :mod:`.management`.

Every scan, around the association: the tracks' existence is predicted (``survival``), free
slots are parked; after the association each pair's IPDA existence update (Musicki, Evans &
Stankovic 1994) with that pair's likelihood ratio (the JIPDA-style shared ratio with
``shared_existence``), the innovation bias test's means where the management has one, hits and
misses, M-of-N confirmation and deletion, the coalescence test where the management has one, and
tentative tracks from the detections no track explains (the management's initiator; by the
association probabilities with ``explained_by: association``). An associator that forms no
shared ratio or no association probabilities (``None`` in its step) gets the IPDA ratio and the
gates. The confirmed tracks whose existence is at least ``report_existence`` are reported
(:class:`~.management.TrackReport`), with the states the associator reports (a smoother's
smoothed states) where it gives them; the coalescence test compares those.

Shapes: ``B`` runs, ``K`` scans, ``C`` track slots, ``S`` pairs, ``M`` detections per list, ``n``
state dimension.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from ..measurements import MeasurementModel
from .coalescence import CoalescenceTest, merged_existence
from .management import EXPLAINED, Management, TableTracks
from .roles import AssociationStep


class OwnTracks(TableTracks):
    """Tracks started from the detections (module docstring): ``management`` the components,
    ``model`` the detections' measurement model, ``n`` the state dimension, ``detection_probability``
    what a pair's existence update takes as ``Pd Pg`` (the detection probability times the gate
    probability; ``Pd`` alone where no gate is applied)."""

    def __init__(self, management: Management, model: MeasurementModel, n: int, detection_probability: float,
                 dtype=torch.float64, **initiate):
        self.mg, self.model, self.n, self.pd_pg, self.dtype = management, model, n, detection_probability, dtype
        self.pos = list(model.pos_idx)
        self.initiate = initiate  # what the initiator reads besides the detections (routes of pooled lists)
        self.started = None

    def begin(self, B: int, K: int, F: torch.Tensor | None = None, Q: torch.Tensor | None = None) -> None:
        self.start_table(B, K, self.model, self.n, self.dtype, None if F is None else F.device)
        self.mg.initiator.begin(B, F, Q)
        rule = self.mg.coalescence
        self.merging = None if rule is None else CoalescenceTest(rule, B, self.pos + list(self.model.vel_idx),
                                                                 None if F is None else F.device)

    def predicted(self, k: int) -> None:
        self.predict_table(self.mg.survival)

    def updated(self, k: int, step: AssociationStep, z: torch.Tensor, valid: torch.Tensor) -> None:
        table, mg = self.table, self.mg
        table.g = step.posterior
        ratio = step.shared_ratio if mg.shared_existence and step.shared_ratio is not None else step.ratio
        S = ratio.shape[-1]
        for j in range(S):
            table.update_existence(ratio[..., j], self.pd_pg)
            if mg.bias is not None:
                table.update_bias(mg.bias, j, S, step.whitened[:, :, j])
        table.record(step.detected, mg.hit_pairs)
        table.manage(mg.confirmer, mg.deleter, self.pos, mg.bias)
        if self.merging is not None:
            now = table.g if step.reported is None else step.reported
            merged = self.merging.step(now.x, now.P, table.confirmed, table.track_id)
            if bool(merged.any()):
                table.existence = merged_existence(table.existence, merged)
                table.free(merged.any(1))
        # new tracks are tentative, so reporting before or after starting them is the same
        self.report.write(k, table if step.reported is None else replace(table, g=step.reported), mg.report_existence)
        by_gate = mg.explained_by == "gate" or step.taken is None
        unused = valid & ~(step.explained if by_gate else step.taken >= EXPLAINED)
        # the initiator hears every scan (a multi-scan one keeps its candidates across scans)
        new = mg.initiator.initiate(z, unused, self.model, self.n, mg.other_sd, **self.initiate)
        self.started = None
        if bool(unused.any()):
            before = table.active
            table.add(*new, mg.initial_existence)
            C = table.active.shape[1]
            self.started = table.active & ~torch.cat([before, before.new_zeros(before.shape[0], C - before.shape[1])], 1)
            # the initiation scan is a hit: with confirm_m 1 a new track is confirmed, and
            # reported, at the scan that started it
            at_once = self.started & mg.confirmer.confirms(table.hits)
            if bool(at_once.any()):
                table.confirm(at_once)
                self.report.write(k, table, mg.report_existence, only=at_once)
