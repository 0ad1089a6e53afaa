"""The multisensor belief-propagation tracker (:mod:`pmsr_nn.trackers.bp_tracker`) on the
detections, ``kind: bp``: a TOMB/P filter with BP association, pair by pair, that starts,
confirms and deletes its own tracks by their existence.

Options:

* the model: ``gate_probability``; ``survival`` per scan; ``birth_rate`` (new targets expected
  per scan) and ``initial_targets`` (undetected targets expected at the first scan), the
  undetected targets' Poisson intensity, spread like the clutter;
* the management, by existence: ``confirm_existence`` (a potential target at or above it is
  confirmed), ``delete_existence`` (below it a track is deleted, and a detection's new potential
  target is not kept), ``report_existence`` (a confirmed track is reported while at or above it);
* new potential targets: with azimuth, one per detection, its velocity prior
  ``birth_velocity_sd_mps`` per axis; without azimuth, tentative tracks from the multi-pair
  initiator (``init_pairs``, ``init_gate_probability``) at ``initial_existence``, from one scan
  (``init_scans: 1``) or from candidates consistent over 2 or 3 scans (``init_scans``,
  ``init_scan_gate_probability``: the multi-scan initiator, as in :mod:`.track_management`);
* the message passing: ``iterations`` at most, until the largest change of a message is at most
  ``tolerance``.

The defaults were chosen on draws no recorded study uses (seeds 1000-1003 of one_sky, the demo's
one sky, dense_crossing and shared_drones; evaluate/RESULTS.md, "Belief propagation"), the same
in every scenario: ``survival`` 0.9975 (a 400-scan expected life, the drones'), so a track that
misses at every pair of a scan is no longer reported, and ``birth_velocity_sd_mps`` 10 (a drone's
speed per axis), so a newly seeded target's position does not spread onto its neighbours'
detections before its velocity is known, and ``delete_existence`` 1e-6, so the new potential
target of a detection that a track (perhaps a ghost of a formation, a mix of its members'
detections) may explain is kept and can win the detections over the scans that follow.

The clutter rate and Pd are the scenario's (the detection list's clutter per scan, floored as the
JPDA's). ``bp`` reads the per-pair lists (the illuminator given); ``bp_3d`` reads, where the
scenario pools them (``illuminator_known: false``), the lists a receiver of a single-frequency
network has, the illuminator of each detection unknown: each pair reads its receiver's pooled
list in turn, so the illuminator is a third dimension of the association (as PMHT-3D's), and a
detection seeds a new potential target under each illuminator, the wrong ones finding no
support at the other receivers. (A detection may then be a track's under two illuminators at
once: the association does not tie the pairs of one receiver together.)
"""

from __future__ import annotations

from ..errors import ConfigError
from ..trackers.base import Estimates
from ..trackers.bp_tracker import BPSettings, bp_tracker
from ..trackers.jpda import floored_clutter_density
from ..trackers.roles import Initiator
from ..trackers.spherical_initiator import SphericalInitiator
from .track_management import INIT_SCAN_OPTIONS, initiator
from . import MIN_CLUTTER_PER_SCAN, MethodCall, MethodKind, Option, register

EXISTENCE = dict(kind=float, lo=1e-12, hi=1.0 - 1e-12)


def settings(spec, sensing) -> BPSettings:
    """The BP settings of a row (``spec``) on a case's ``sensing``; one-line refusals naming the
    row of settings that could never confirm a track. The clutter is a pair's list's, or a
    receiver's pooled list's for ``bp_3d`` where the scenario pools them."""
    o = spec.option
    clutter = sensing.clutter if _pooled(spec, sensing) else sensing.pair_clutter()
    try:
        return BPSettings(pd=float(sensing.pd), clutter_count=max(float(clutter.per_scan), MIN_CLUTTER_PER_SCAN),
                          clutter_density=floored_clutter_density(clutter, sensing.detection_model.components),
                          gate_probability=float(o("gate_probability")),
                          survival=float(o("survival")), birth_rate=float(o("birth_rate")),
                          initial_targets=float(o("initial_targets")), confirm_existence=float(o("confirm_existence")),
                          delete_existence=float(o("delete_existence")), report_existence=float(o("report_existence")),
                          initial_existence=float(o("initial_existence")), iterations=int(o("iterations")),
                          tolerance=float(o("tolerance")))
    except ConfigError as exc:
        raise ConfigError(f"method {spec.name!r}: {exc}") from None


def _initiator(spec) -> Initiator:
    pairs = spec.option("init_pairs")
    return initiator(SphericalInitiator(float(spec.option("birth_velocity_sd_mps")), None if pairs is None else int(pairs),
                                        float(spec.option("init_gate_probability"))), spec)


def check_sensing(spec, sensing) -> None:
    """Refuses, in one line naming the row, settings that could never confirm a track, and
    detections no new potential target can be seeded from."""
    settings(spec, sensing)
    model = sensing.detection_model
    if _pooled(spec, sensing) and "azimuth" not in model.components:
        raise ConfigError(f"method {spec.name!r}: kind bp_3d reads lists pooled per receiver only where each pair "
                          f"measures azimuth (a detection seeds a target under each illuminator); the detections "
                          f"measure {list(model.components)} (use kind bp)")
    if "azimuth" in model.components and int(spec.option("init_scans")) != 1:
        raise ConfigError(f"method {spec.name!r}: option init_scans is read only without azimuth (with it, each "
                          f"detection seeds a potential target); the detections measure {list(model.components)}")
    if "azimuth" not in model.components:
        try:
            _initiator(spec).check(model, "BP without azimuth (tracks from the multi-pair initiator)")
        except ConfigError as exc:
            raise ConfigError(f"method {spec.name!r}: {exc}") from None


def _pooled(spec, sensing) -> bool:
    """Whether the row reads lists pooled per receiver: ``bp_3d`` where the scenario pools them."""
    return spec.kind == "bp_3d" and not sensing.illuminator_known


def run_bp(call: MethodCall) -> Estimates:
    m, s, det = call.models, call.sensing, call.product
    model = s.detection_model
    pooled = _pooled(call.spec, s)
    scans = det.pooled.scans if pooled else det.scans
    rep = bp_tracker(scans, m.motion, m.dt, m.q, model, model.R(device=scans.z.device),
                     settings(call.spec, s), s.prior_sd, float(call.spec.option("birth_velocity_sd_mps")),
                     None if "azimuth" in model.components else _initiator(call.spec),
                     routes=det.pooled.routes if pooled else None)
    return Estimates(rep.x, rep.exists, rep.P, paired=False, existence=rep.existence)


OPTIONS = {"gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12),
           "survival": Option(0.9975, float, 1e-6, 1.0),
           "birth_rate": Option(0.01, float, 0.0, 1e3), "initial_targets": Option(0.01, float, 0.0, 1e3),
           "confirm_existence": Option(0.9, **EXISTENCE), "delete_existence": Option(1e-6, **EXISTENCE),
           "report_existence": Option(0.5, **EXISTENCE), "initial_existence": Option(0.1, **EXISTENCE),
           "birth_velocity_sd_mps": Option(10.0, float, 1e-3, 1e5),
           "init_pairs": Option(None, int, 1, 64, nullable=True, null="every pair (the multi-pair initiator, without "
                                                                       "azimuth)"),
           "init_gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12), **INIT_SCAN_OPTIONS,
           "iterations": Option(100, int, 1, 100_000), "tolerance": Option(1e-8, float, 0.0, 1.0)}
register(MethodKind("bp", "detections", run_bp, OPTIONS, check_sensing=check_sensing, starts_tracks=True,
                    any_device=True, batchable=True,
                    description="multisensor belief-propagation tracker (TOMB/P with BP association, Meyer et al., "
                                "Proc. IEEE 2018), pair by pair; starts, confirms and deletes its own tracks by existence"))
register(MethodKind("bp_3d", "detections", run_bp, OPTIONS, check_sensing=check_sensing, starts_tracks=True,
                    # not batchable: its pooled lists, padded to the longest run's, made a joined call slower
                    # (benchmarks/RESULTS.md, "Several blocks per tracker call")
                    pooled_lists=True, any_device=True,
                    description="the belief-propagation tracker on the lists a single-frequency-network receiver has "
                                "(pooled, the illuminator unknown: each pair reads its receiver's list); elsewhere as bp"))
