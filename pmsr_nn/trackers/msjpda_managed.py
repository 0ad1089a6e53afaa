"""S-/P-MSJPDA that start, confirm and delete their own tracks: the JPDA associators of
:mod:`.jpda_associators` with the management :class:`~.own_tracks.OwnTracks` on the one tracker
loop, with the innovation bias test (:mod:`.innovation_bias`) where asked for."""

from __future__ import annotations

from typing import Literal

import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..motion import KinematicModel
from ..simulation.detections import Scans
from .jpda_associators import Association
from .loop import run_tracker
from .management import Management, TrackReport
from .msjpda import JPDASettings, associator, check_scans, check_variant
from .own_tracks import OwnTracks


def managed_msjpda(scans: Scans, motion: KinematicModel, dt: float, q: float, model: MeasurementModel, R: torch.Tensor,
                   settings: JPDASettings, architecture: Literal["sequential", "parallel"],
                   management: Management, association: Association = "jpda") -> TrackReport:
    """S-/P-MSJPDA that start, confirm and delete their own tracks (:class:`~.own_tracks.OwnTracks`).

    Every scan: predict the tracks, associate and update them as :func:`~.msjpda.msjpda` does
    (tentative and confirmed tracks alike), update their existence probabilities (IPDA: each
    pair's gated detections against clutter, ``Pd Pg``; or JIPDA-style from the association
    probabilities), count at how many pairs each was detected, confirm and delete, merge tracks
    that coalesce (the management's coalescence test), then start tentative tracks from the
    detections no track explains (gates, or association probabilities: the management's
    ``explained_by``).
    Step 0 has no prediction. Returns the confirmed tracks as reported at each scan (those whose
    existence is at least the management's ``report_existence``).

    ``association`` (sequential only): see :func:`~.jpda_associators.pair_update`.
    """
    check_scans(scans, model)
    check_variant(architecture, association)
    if management.bias is not None and architecture == "parallel":
        raise ConfigError("the innovation bias test reads per-pair innovations (sequential MSJPDA only)")
    management.check(model, f"{architecture} MSJPDA")
    tracks = OwnTracks(management, model, motion.dim_x, settings.pd * settings.gate_probability, scans.z.dtype)
    return run_tracker(scans, motion, dt, q, associator(model, R, settings, architecture, association),
                       tracks)
