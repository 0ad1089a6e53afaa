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
given), also where the scenario pools them per receiver. Tracks start at each target's birth
from its initiation prior, as S-/P-MSJPDA's do, and associate only while the target lives.

Stone Soup tracks one run at a time: the runs of a block are a Python loop. Extras for the
S-MSJPDA paper's loss rule: ``dummy_most_probable (B, K, N)`` (at every pair no detection was
the likeliest association: JPDA's missed-detection probability at least each detection's; GNN
assigned none) and ``gate_range_sd_m (B, K, N)`` (largest predicted bistatic-range deviation over
the pairs, R included).
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import ConfigError
from ..trackers.base import Estimates
from . import MethodCall, MethodKind, Option, register
from .msjpda import clutter_density

TRACKERS = ("jpda", "gnn")


def _interop():
    """:mod:`pmsr_nn.interop.stonesoup` (a one-line :class:`ConfigError` without Stone Soup)."""
    from ..interop import stonesoup

    return stonesoup


def _components(tracker: str, pair_models: list, transition, pd: float, density: float,
                gate_probability: float) -> tuple[list, list]:
    """Per pair: Stone Soup's associator and updater for ``tracker``."""
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
    return associators, updaters


def run_stonesoup(call: MethodCall) -> Estimates:
    ss = _interop()
    from stonesoup.types.track import Track

    m, sensing, det = call.models, call.sensing, call.product
    tracker = call.spec.option("tracker")
    scans, prior = det.scans, det.prior
    B, K, N, _ = scans.shape
    T, n = prior.x.shape[1:]
    model = sensing.detection_model
    pair_models = [ss.measurement_model(model.for_pairs([p]), n) for p in range(N)]
    associators, updaters = _components(tracker, pair_models, ss.transition_model(m.motion, m.q), sensing.pd,
                                        clutter_density(sensing), float(call.spec.option("gate_probability")))
    times = ss.scan_times(K, m.dt)
    alive = call.alive.numpy()
    births = alive.argmax(0)
    dummy = np.zeros((B, K, T), dtype=bool)
    gate_sd = np.full((B, K, T), np.nan)
    runs = []
    for b in range(B):
        lists = ss.scan_detections(scans.z[b], scans.valid[b], pair_models, m.dt)
        tracks = [Track() for _ in range(T)]
        for k in range(K):
            for t in np.flatnonzero(births == k):
                tracks[t].append(ss.gaussian_state(prior.x[b, t], prior.P[b, t], times[k]))
            live = [t for t in range(T) if alive[k, t]]
            if not live:
                continue
            missed = np.ones(len(live), dtype=bool)
            sd = np.zeros(len(live))
            for p in range(N):
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
                    S = updaters[p].predict_measurement(prediction).covar  # cached: the update made it
                    sd[i] = max(sd[i], float(np.sqrt(S[0, 0])))
            dummy[b, k, live], gate_sd[b, k, live] = missed, sd
        runs.append(tracks)
    est = ss.tracks_to_estimates(runs, K, m.dt, n)
    live = call.alive.expand(B, K, T)
    if not bool((est.exists == live).all()):  # a track holds a state exactly while its target lives
        raise RuntimeError("Stone Soup tracks do not cover the targets' lives")
    est.extras = {"dummy_most_probable": torch.from_numpy(dummy) & live, "gate_range_sd_m": torch.from_numpy(gate_sd)}
    return est


def _check(spec, alive: torch.Tensor, resource, case: str) -> None:
    """Stone Soup must be installed (a one-line error naming the method otherwise)."""
    try:
        _interop()
    except ConfigError as exc:
        raise ConfigError(f"method {spec.name!r} (kind stonesoup): {exc}") from None


OPTIONS = {"tracker": Option("jpda", str, choices=TRACKERS), "gate_probability": Option(0.999, float, 0.5, 1.0 - 1e-12)}
register(MethodKind("stonesoup", "detections", run_stonesoup, OPTIONS, check=_check, multi_target=True,
                    description="Stone Soup 1.9.1's JPDA or GNN (EKF, sequential over pairs), tracks started as "
                                "S-MSJPDA's: a peer beside ours"))
