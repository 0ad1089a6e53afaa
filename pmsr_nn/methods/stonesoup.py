"""Stone Soup's trackers on the detections, a peer beside ours (``pip install "pmsr-nn[stonesoup]"``).

``tracker`` picks the data association; both use Stone Soup's EKF predictor with our motion model
(its ``F`` and ``Q``), its ``PDAHypothesiser`` (the case's Pd and clutter density, floored as for
S-/P-MSJPDA, and ``gate_probability``) and, per transmitter-receiver pair, our measurement model
(:mod:`pmsr_nn.interop.stonesoup`):

* ``jpda``: Stone Soup's ``JPDA`` associator (every joint event enumerated) and ``PDAUpdater``;
* ``gnn``: its ``GNNWith2DAssignment`` (the most probable joint assignment) and the EKF update.

Stone Soup's associators take one list of detections per call, so the pairs' lists update the
tracks one after another at each scan (a zero-interval prediction between them): the sequential
multi-sensor update of S-MSJPDA. The per-pair lists are read (the illuminator of each detection
given), also where the scenario pools them per receiver.

How tracks start (option ``initiation``):

* ``oracle`` (default): at each target's birth from its initiation prior, as S-/P-MSJPDA's do;
  a track associates only while its target lives. Slot ``i`` is target ``i`` (paired
  estimates). Extras for the S-MSJPDA paper's loss rule: ``dummy_most_probable (B, K, N)`` (at
  every pair no detection was the likeliest association: JPDA's missed-detection probability at
  least each detection's; GNN assigned none) and ``gate_range_sd_m (B, K, N)`` (largest
  predicted bistatic-range deviation over the pairs, R included).
* ``detections``: Stone Soup's own track management, as its ``MultiTargetMixtureTracker``
  (``jpda``) or ``MultiTargetTracker`` (``gnn``) runs it, with the update kept sequential over
  the pairs. At each pair's list the confirmed tracks are associated and updated; the detections
  no confirmed track took (JPDA: none of its hypotheses with the detection more probable than its
  missed detection) that fix a position go to Stone Soup's ``MultiMeasurementInitiator``. That
  associates its tentative tracks with them (a GNN, ``GNNWith2DAssignment`` over the same
  ``PDAHypothesiser``, each detection with its own pair's model), deletes tentative tracks with
  an ``UpdateTimeStepsDeleter(tentative_delete_after_misses)`` (Stone Soup counts scans at
  every call: a tentative track must be detected again by the call that comes
  ``tentative_delete_after_misses`` scans after its last detection, or earlier) and starts one
  from each detection left (``SinglePointMeasurementInitiator``: the prior centred on the
  detection's position fix, :meth:`~pmsr_nn.interop.stonesoup.BistaticMeasurement.inverse_function`,
  deviations ``init_position_sd_m``, ``init_velocity_sd_mps`` and the initiation prior's for the
  rest, updated with the detection: its range-rate gives the velocity along the bistatic
  gradient). A tentative track with ``confirm_points`` updates (at most one per pair and scan,
  its first detection counted) is confirmed: reported from that scan on, and updated by the next
  pairs of the same scan already. After every scan an ``UpdateTimeStepsDeleter
  (delete_after_misses)`` deletes the confirmed tracks without a detection at any pair in the
  last ``delete_after_misses`` scans (JPDA: a scan where no detection was more probable than the
  missed detection counts as a miss); they are not reported from that scan on. Estimates are
  unpaired: slot ``i`` is the ``i``-th track confirmed in its run (order within a pair and scan:
  by the first state), ``M`` the most of a run; ``exists`` from its confirmation to its deletion.
  No loss-rule extras (the rule needs a track per target). Only detections with a bistatic range
  (or delay) and an azimuth at every pair, in a planar geometry, fix a position.

Stone Soup tracks one run at a time: the runs of a block are a Python loop.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import ConfigError
from ..trackers.base import Estimates
from . import MethodCall, MethodKind, Option, register
from .kind_metrics import TrackLoss
from .track_management import clutter_density

TRACKERS = ("jpda", "gnn")


def _interop():
    """:mod:`pmsr_nn.interop.stonesoup` (a one-line :class:`ConfigError` without Stone Soup)."""
    from ..interop import stonesoup

    return stonesoup


def _components(tracker: str, pair_models: list, transition, pd: float, density: float,
                gate_probability: float) -> tuple[list, list, object]:
    """Per pair: Stone Soup's associator and updater for ``tracker``; and the predictor."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDA
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor
    from stonesoup.updater.kalman import ExtendedKalmanUpdater
    from stonesoup.updater.probability import PDAUpdater

    predictor = ExtendedKalmanPredictor(transition)
    updaters = [(PDAUpdater if tracker == "jpda" else ExtendedKalmanUpdater)(measurement_model=mm) for mm in pair_models]
    associate = JPDA if tracker == "jpda" else GNNWith2DAssignment
    associators = [associate(PDAHypothesiser(predictor, u, clutter_spatial_density=density, prob_detect=pd,
                                             prob_gate=gate_probability)) for u in updaters]
    return associators, updaters, predictor


def run_stonesoup(call: MethodCall) -> Estimates:
    if call.spec.option("initiation") == "detections":
        return _run_initiating(call)
    ss = _interop()
    from stonesoup.types.track import Track

    m, sensing, det = call.models, call.sensing, call.product
    tracker = call.spec.option("tracker")
    scans, prior = det.scans, det.prior
    B, K, S, _ = scans.shape
    N, n = prior.x.shape[1:]
    model = sensing.detection_model
    pair_models = [ss.measurement_model(model.for_pairs([p]), n) for p in range(S)]
    associators, updaters, _ = _components(tracker, pair_models, ss.transition_model(m.motion, m.q), sensing.pd,
                                           clutter_density(sensing), float(call.spec.option("gate_probability")))
    times = ss.scan_times(K, m.dt)
    alive = call.alive.numpy()
    births = alive.argmax(0)
    dummy = np.zeros((B, K, N), dtype=bool)
    gate_sd = np.full((B, K, N), np.nan)
    runs = []
    for b in range(B):
        lists = ss.scan_detections(scans.z[b], scans.valid[b], pair_models, m.dt)
        tracks = [Track() for _ in range(N)]
        for k in range(K):
            for t in np.flatnonzero(births == k):
                tracks[t].append(ss.gaussian_state(prior.x[b, t], prior.P[b, t], times[k]))
            live = [t for t in range(N) if alive[k, t]]
            if not live:
                continue
            missed = np.ones(len(live), dtype=bool)
            sd = np.zeros(len(live))
            for p in range(S):
                hyps = associators[p].associate([tracks[t] for t in live], lists[k][p], times[k])
                for i, t in enumerate(live):
                    h = hyps[tracks[t]]
                    if tracker == "jpda":
                        tracks[t].append(updaters[p].update(h))
                        w_miss = sum(float(x.probability) for x in h if not x)
                        missed[i] &= all(w_miss >= float(x.probability) for x in h if x)
                        prediction = h[0].prediction
                    else:
                        tracks[t].append(updaters[p].update(h) if h else h.prediction)
                        missed[i] &= not h
                        prediction = h.prediction
                    innovation = updaters[p].predict_measurement(prediction).covar  # cached: the update made it
                    sd[i] = max(sd[i], float(np.sqrt(innovation[0, 0])))
            dummy[b, k, live], gate_sd[b, k, live] = missed, sd
        runs.append(tracks)
    est = ss.tracks_to_estimates(runs, K, m.dt, n)
    live = call.alive.expand(B, K, N)
    if not bool((est.exists == live).all()):  # a track holds a state exactly while its target lives
        raise RuntimeError("Stone Soup tracks do not cover the targets' lives")
    est.extras = {"dummy_most_probable": torch.from_numpy(dummy) & live, "gate_range_sd_m": torch.from_numpy(gate_sd)}
    return est


def _initiator_prior(call: MethodCall, n: int):
    """The prior a tentative track starts from before its first detection's update: mean zero
    (the detection's fix replaces the position), deviations ``init_position_sd_m`` on the
    positions, ``init_velocity_sd_mps`` on the velocities and the initiation prior's elsewhere
    (accelerations)."""
    from stonesoup.types.array import CovarianceMatrix, StateVector
    from stonesoup.types.state import GaussianState

    motion, spec = call.models.motion, call.spec
    sd = call.sensing.prior_sd.detach().cpu().to(torch.float64).numpy().copy()
    sd[list(motion.pos_idx)] = float(spec.option("init_position_sd_m"))
    sd[list(motion.vel_idx)] = float(spec.option("init_velocity_sd_mps"))
    return GaussianState(StateVector(np.zeros((n, 1))), CovarianceMatrix(np.diag(sd**2)))


def _run_initiating(call: MethodCall) -> Estimates:
    """``initiation: detections``: Stone Soup's own track management (module docstring)."""
    ss = _interop()
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.deleter.time import UpdateTimeStepsDeleter
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.initiator.simple import MultiMeasurementInitiator, SinglePointMeasurementInitiator
    from stonesoup.types.prediction import GaussianStatePrediction
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    m, sensing, det, spec = call.models, call.sensing, call.product, call.spec
    tracker = spec.option("tracker")
    scans = det.scans
    B, K, S, _ = scans.shape
    n = m.motion.dim_x
    model = sensing.detection_model
    pair_models = [ss.measurement_model(model.for_pairs([p]), n) for p in range(S)]
    _check_fixes(spec, pair_models)
    density, gate = clutter_density(sensing), float(spec.option("gate_probability"))
    associators, updaters, predictor = _components(tracker, pair_models, ss.transition_model(m.motion, m.q), sensing.pd,
                                                   density, gate)
    prior = _initiator_prior(call, n)
    deleter = UpdateTimeStepsDeleter(time_steps_since_update=int(spec.option("delete_after_misses")))
    times = ss.scan_times(K, m.dt)
    runs, spans = [], []
    for b in range(B):
        lists = ss.scan_detections(scans.z[b], scans.valid[b], pair_models, m.dt)
        # tentative tracks: Stone Soup's multi-measurement initiator, a GNN over the detections no
        # confirmed track took (each detection's own pair model: one initiator serves every pair)
        updater = ExtendedKalmanUpdater(measurement_model=pair_models[0])
        initiator = MultiMeasurementInitiator(
            prior_state=prior, deleter=UpdateTimeStepsDeleter(int(spec.option("tentative_delete_after_misses"))),
            data_associator=GNNWith2DAssignment(PDAHypothesiser(predictor, updater, clutter_spatial_density=density,
                                                                prob_detect=sensing.pd, prob_gate=gate)),
            updater=updater, min_points=int(spec.option("confirm_points")),
            initiator=SinglePointMeasurementInitiator(prior, updater=updater))
        confirmed, tracks, life = [], [], []  # live confirmed tracks; every confirmed track and its [first, end) scans
        for k in range(K):
            for p in range(S):
                taken = set()
                if confirmed:
                    hyps = associators[p].associate(confirmed, lists[k][p], times[k])
                    for track in confirmed:
                        h = hyps[track]
                        if tracker == "jpda":  # as Stone Soup's MultiTargetMixtureTracker
                            post = updaters[p].update(h)
                            miss = next(x.probability for x in h if not x)
                            hits = [x.measurement for x in h if x and x.probability > miss]
                            track.append(post if hits else GaussianStatePrediction(post.state_vector, post.covar,
                                                                                 timestamp=times[k]))
                        else:  # as its MultiTargetTracker
                            hits = [h.measurement] if h else []
                            track.append(updaters[p].update(h) if h else h.prediction)
                        taken.update(hits)
                free = {d for d in lists[k][p] if d not in taken and d.measurement_model.fixes_position(d)}
                new = sorted(initiator.initiate(free, times[k]), key=_first_fix)
                for track in new:  # confirmed now: the next pairs of this scan update it already
                    life.append([k, K])
                    tracks.append(track)
                    confirmed.append(track)
            for track in deleter.delete_tracks(set(confirmed)):  # not reported from this scan on
                life[_index(tracks, track)][1] = k
                confirmed.remove(track)
        runs.append(tracks)
        spans.append(life)
    return ss.tracks_to_estimates(runs, K, m.dt, n, reported=spans)


def _first_fix(track) -> tuple:
    """A track's order among those confirmed at one pair and scan: its first state's mean
    (Stone Soup returns a set; the order fixes the track ids)."""
    return tuple(np.asarray(track[0].state_vector, dtype=np.float64)[:, 0])


def _index(tracks: list, track) -> int:
    return next(i for i, t in enumerate(tracks) if t is track)


def _check_fixes(spec, pair_models: list) -> None:
    """``initiation: detections`` starts tracks from one pair's position fix: every pair needs a
    range (or delay) and an azimuth, in a planar geometry."""
    bad = [p + 1 for p, mm in enumerate(pair_models) if mm.fix_rows is None]
    if bad:
        raise ConfigError(f"method {spec.name!r} (kind stonesoup): initiation: detections starts tracks from a pair's "
                          f"bistatic range (or delay) and azimuth in a planar geometry; pair(s) {bad} of "
                          f"{pair_models[0].model.components} have none")


def _check(spec, alive: torch.Tensor, resource, case: str) -> None:
    """Stone Soup must be installed (a one-line error naming the method otherwise)."""
    try:
        _interop()
    except ConfigError as exc:
        raise ConfigError(f"method {spec.name!r} (kind stonesoup): {exc}") from None


def _check_sensing(spec, sensing) -> None:
    """``initiation: detections`` needs detections whose pairs fix positions (also checked when
    the method runs)."""
    if spec.option("initiation") != "detections" or sensing.detection_model is None:
        return
    _check(spec, None, None, "")
    ss = _interop()
    model = sensing.detection_model
    n = int(sensing.prior_sd.shape[0])
    _check_fixes(spec, [ss.measurement_model(model.for_pairs([p]), n) for p in range(model.n_pairs)])


INITIATIONS = ("oracle", "detections")
OPTIONS = {"tracker": Option("jpda", str, choices=TRACKERS), "gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12),
           "initiation": Option("oracle", str, choices=INITIATIONS),
           # Stone Soup's track management, with initiation: detections. Defaults chosen on runs 10-19 of
           # evaluate/shared_drones.yaml (3 pairs, Pd 0.9, 10 clutter points per pair and scan): 3
           # confirm points gave 1.3 false tracks per run, 4 none (5: none, a later first track); a tentative
           # track kept 2 scans confirmed ~0.5 s sooner but cost 2.3 times the run time (its clutter tracks)
           "confirm_points": Option(4, int, 1, 10_000), "tentative_delete_after_misses": Option(1, int, 1, 10_000),
           "delete_after_misses": Option(3, int, 1, 10_000), "init_velocity_sd_mps": Option(20.0, float, 1e-3, 1e5),
           "init_position_sd_m": Option(2000.0, float, 1.0, 1e7)}
register(MethodKind("stonesoup", "detections", run_stonesoup, OPTIONS, check=_check, check_sensing=_check_sensing,
                    metrics=(TrackLoss(),), any_device=lambda spec, sensing: (False, " (Stone Soup is NumPy)"),
                    description="Stone Soup 1.9.1's JPDA or GNN (EKF, sequential over pairs), tracks started as "
                                "S-MSJPDA's or by its own initiator and deleter: a peer beside ours"))
