"""One pair's SMC-PHD in the bistatic plane and its known-association reference (Daniyan et al.).

Kind ``smc_phd_pair`` runs the SMC-PHD filter of :mod:`pmsr_nn.trackers.phd` on the detections
of one transmitter-receiver pair (option ``pair``), in that pair's bistatic plane ``[r, rdot]``:
bistatic range (m) and range-rate (m/s), the seed's CV model with process deviation
``process_sd_mps2``. Its estimates are labelled by GTDA or by the Hungarian baseline
(:func:`pmsr_nn.trackers.labelling.label_tracks`), or reported unlabelled (``labelling: none``:
the PHD's own estimates, one set per scan). Nobody hands it the births.

Kind ``known_association_kf_pair`` is the reference of what association can reach with the same
motion model: per run and target, the exact Kalman filter on exactly the detections that target
caused (it reads the detections' true origins), started at its first detection (births known).
Its rows are marked ``initiation: association known``.

Both read range and range-rate (detections of Doppler are turned into range-rate with the pair's
carrier, ``rdot = -f_D c / f_c``; their deviation likewise), with the deviations of the scenario's
detection model; the PHD uses the case's Pd and a clutter intensity per m x m/s: the clutter rate
of one pair over the clutter box's range x range-rate extent (for detections of Doppler, the
Doppler extent in m/s), floored as the other trackers'.

Births (options ``births``, ``birth_particles_min``, :class:`~pmsr_nn.trackers.phd.PHDSpec`):
``adaptive`` (the default since issue 37) seeds births only on the previous scan's detections the
persistent PHD did not explain, ``particles_per_birth`` particles for a scan's whole birth mass,
at least ``birth_particles_min`` per unexplained detection, so clutter costs little;
``every_detection`` puts ``particles_per_birth`` particles on every detection (the filter before).

Scoring: their estimates are not the scenario's state, so each kind declares its space
(:class:`~pmsr_nn.methods.EstimateSpace`): the pair's ``[r, rdot]``. The runner projects the
truth into it (the measurement model's range and range-rate of the pair, noise-free) and scores
OSPA / GOSPA and "position" errors on the bistatic range alone (one axis, in metres) and
"velocity" errors on the range-rate; the report labels those rows with their space.

Random streams: the PHD filter draws from ``(seed, case, block, crc32("smcphd"))``, one stream
shared by every ``smc_phd_pair`` row of a block, so rows that differ only in their labelling
read the same PHD run: it runs once per block and settings and is kept for the other rows (a
small per-process cache keyed by the block's detections, the block's seed words and the PHD's
settings; identical inputs give identical outputs, so the cache changes no number). Each
labelling draws from ``(seed, case, block, crc32(name))``. A row's seconds count the PHD's in
full (measured where it ran, added where it was read from the cache: ``shared_seconds``) plus
its own labelling, so each row costs what it would alone.
"""

from __future__ import annotations

import time
from dataclasses import replace

import torch

from ..errors import ConfigError
from ..filters.gaussian import Gaussian, MeasurementMoments, kalman_update, predict
from ..measurements import SPEED_OF_LIGHT, MeasurementModel
from ..rng import seeded_generator
from ..trackers.base import Estimates
from ..trackers.gtda import GameSpec
from ..trackers.labelling import LabelSpec, label_tracks
from ..trackers.phd import PHDSpec, SMCPHD, cv_matrices
from . import MIN_CLUTTER_PER_SCAN, EstimateSpace, MethodCall, MethodKind, Option, ReadWhen, method_stream, register
from .kind_metrics import Labelling, PHDFigures, Unlabelled
from .track_management import COALESCENCE_OPTIONS, coalescence

PHD_STREAM = method_stream("smcphd")
"""Last seed word of the PHD filter's generator (the former study's, so its draws are the same)."""

RATE_COMPONENTS = ("range_rate", "doppler")


# ------------------------------------------------------------------ the pair's detections


def _rate_component(model: MeasurementModel) -> str:
    return next(c for c in model.components if c in RATE_COMPONENTS)


def pair_deviations(model: MeasurementModel, pair: int, device=None) -> torch.Tensor:
    """The detections' deviations ``(2,)`` of bistatic range (m) and range-rate (m/s), on ``device``."""
    comps = list(model.components)
    rate = _rate_component(model)
    sd_r, sd_v = float(model.noise_std[comps.index("range")]), float(model.noise_std[comps.index(rate)])
    if rate == "doppler":
        sd_v = sd_v * SPEED_OF_LIGHT / float(model.geometry.pair_carriers()[pair])
    return torch.tensor([sd_r, sd_v], dtype=torch.float64, device=device)


def pair_detections(call: MethodCall, pair: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The pair's detections ``z (B, K, J, 2)`` ``[r, rdot]`` (NaN padding), ``valid (B, K, J)`` and
    their true origins ``(B, K, J)``."""
    model = call.sensing.detection_model
    det = call.product.scans
    comps = list(model.components)
    z = det.z[:, :, pair][..., [comps.index("range"), comps.index(_rate_component(model))]]
    if _rate_component(model) == "doppler":  # Doppler (Hz) -> range-rate (m/s)
        z[..., 1] = -z[..., 1] * SPEED_OF_LIGHT / float(model.geometry.pair_carriers()[pair])
    return z, det.valid[:, :, pair], det.origin[:, :, pair]


def pair_clutter_intensity(sensing, pair: int) -> float:
    """Expected clutter per scan and m x m/s of one pair (module docstring), floored."""
    clutter = sensing.pair_clutter()
    model = sensing.detection_model
    if _rate_component(model) == "range_rate":
        volume = clutter.volume_of(("range", "range_rate"))
    else:
        volume = clutter.volume_of(("range", "doppler")) * SPEED_OF_LIGHT / float(model.geometry.pair_carriers()[pair])
    return max(clutter.per_scan, MIN_CLUTTER_PER_SCAN) / volume


# ------------------------------------------------------------------ the estimate space


def pair_space(spec, sensing) -> EstimateSpace:
    """The bistatic plane ``[r, rdot]`` of the method's pair: the truth's noise-free range and range-rate."""
    pair = int(spec.option("pair"))
    model = sensing.detection_model
    tx, rx = model.geometry.pairs[pair]
    plane = MeasurementModel(model.geometry, ("range", "range_rate"), (1.0, 1.0), model.pos_idx, model.vel_idx,
                             layout="pair").for_pairs([pair])
    return EstimateSpace(key=f"pair {pair}", project=plane.h,
                         title=f"bistatic plane of pair {pair} (transmitter {tx}, receiver {rx})",
                         pos_label="bistatic range (m)", vel_label="bistatic range-rate (m/s)")


# ------------------------------------------------------------------ the PHD, once per block and settings

_CACHE: list = []
"""The last PHD runs: ``(product, seed words, settings, estimates, seconds)``, newest first."""

CACHE_SIZE = 4


def phd_settings(spec) -> PHDSpec:
    o = spec.option
    return PHDSpec(particles_per_target=int(o("particles_per_target")), particles_per_birth=int(o("particles_per_birth")),
                   survival=float(o("survival")), birth_rate=float(o("birth_rate")),
                   process_sd_mps2=float(o("process_sd_mps2")), kmeans_iterations=int(o("kmeans_iterations")),
                   estimate_mass=float(o("estimate_mass")), gate_probability=float(o("phd_gate_probability")),
                   adaptive_birth=o("births") == "adaptive", birth_particles_min=int(o("birth_particles_min")))


def run_phd(call: MethodCall):
    """``(filter, estimates, seconds, cached)``: the PHD on the call's pair, or the run a row with the
    same settings made on the same block (module docstring)."""
    spec, s = call.spec, call.sensing
    pair = int(spec.option("pair"))
    dev = call.product.scans.z.device
    settings = (pair, phd_settings(spec), tuple(pair_deviations(s.detection_model, pair, dev).tolist()), float(s.pd),
                pair_clutter_intensity(s, pair), float(call.models.dt))
    phd = SMCPHD(settings[1], torch.tensor(settings[2], dtype=torch.float64, device=dev), settings[3], settings[4],
                 settings[5])
    for product, seed, key, est, seconds in _CACHE:
        if product is call.product and seed == tuple(call.seed) and key == settings:
            return phd, est, seconds, True
    z, valid, _ = pair_detections(call, pair)
    t0 = time.perf_counter()
    est = phd.run(z, valid, seeded_generator(*call.seed, PHD_STREAM, device=dev))
    seconds = time.perf_counter() - t0
    _CACHE.insert(0, (call.product, tuple(call.seed), settings, est, seconds))
    del _CACHE[CACHE_SIZE:]
    return phd, est, seconds, False


def label_settings(spec) -> LabelSpec:
    o = spec.option
    return LabelSpec(method=o("labelling"), gate_probability=float(o("label_gate_probability")),
                     max_missed=int(o("max_missed")), confirm_m=int(o("confirm_m")), confirm_n=int(o("confirm_n")),
                     game=GameSpec(forgetting=float(o("forgetting")), iterations=int(o("game_iterations")),
                                   conflict=float(o("conflict")), alpha_scale=float(o("alpha_scale"))),
                     coalescence=coalescence(o))


def run_smc_phd_pair(call: MethodCall) -> Estimates:
    """Unpaired tracks ``x (B, K, tracks, 2)`` in ``[r, rdot]`` (labelled, or the PHD's estimates with
    ``labelling: none``), without covariances; extras: the labelling's, ``phd_expected (B, K)`` (the PHD's integral after
    each update), ``phd_particles (B, K)``, ``phd_seconds`` and ``shared_seconds`` (the PHD's
    seconds where this call read it from the cache, else 0)."""
    spec = call.spec
    phd, est, seconds, cached = run_phd(call)
    extras = {"phd_expected": est.expected, "phd_particles": est.particles, "phd_seconds": seconds,
              "shared_seconds": seconds if cached else 0.0}
    # no covariance goes to the scoring: an estimate's is the weighted spread of its particles (singular
    # for a cluster of copies of one particle), not a filter's error covariance, so no ANEES
    if spec.option("labelling") == "none":  # one set per scan, no identity: no label-following figures
        return Estimates(est.x, est.exists, None, {**extras, "unlabelled": True}, paired=False)
    lab = label_tracks(est.x, est.P, est.exists, phd.F, phd.Q, label_settings(spec),
                       seeded_generator(*call.seed, method_stream(spec.name), device=est.x.device))
    return Estimates(lab.x, lab.exists, None, {**lab.extras, **extras}, paired=False)


# ------------------------------------------------------------------ the known-association reference


def known_association_kf(z: torch.Tensor, origin: torch.Tensor, N: int, F: torch.Tensor, Q: torch.Tensor,
                         R: torch.Tensor, alive: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per run and target, the exact Kalman filter (CV model ``F``, ``Q``; ``H = I``) on exactly the
    detections that target caused (``origin``), started at its first detection (births known).
    ``z (B, K, J, 2)``, ``origin (B, K, J)``; returns ``x (B, K, N, 2)``, ``P (B, K, N, 2, 2)`` and
    ``exists (B, K, N)`` (alive and started)."""
    B, K, J, _ = z.shape
    own = torch.full((B, K, N, 2), float("nan"), dtype=torch.float64, device=z.device)
    b, k, j = torch.nonzero(origin >= 0, as_tuple=True)
    own[b, k, origin[b, k, j]] = z[b, k, j].to(torch.float64)
    x = torch.zeros(B, N, 2, dtype=torch.float64, device=z.device)
    P = R.expand(B, N, 2, 2).clone()
    started = torch.zeros(B, N, dtype=torch.bool, device=z.device)
    xs, Ps, ex = [], [], []
    for k in range(K):
        pred = predict(Gaussian(x, P), F, Q)
        x, P = pred.x, pred.P
        zk = own[:, k]
        seen = torch.isfinite(zk).all(-1)
        post = kalman_update(pred, zk, MeasurementMoments(x, P + R, P), None)[0]  # H = I: z = x, S = P + R, C = P
        first = seen & ~started  # the first detection starts the filter
        x = torch.where(first[..., None], torch.nan_to_num(zk), torch.where(seen[..., None], post.x, x))
        P = torch.where(first[..., None, None], R, torch.where(seen[..., None, None], post.P, P))
        started = (started | seen) & alive[k]
        xs.append(x)
        Ps.append(P)
        ex.append(started.clone())
    return torch.stack(xs, 1), torch.stack(Ps, 1), torch.stack(ex, 1)


def run_known_association_kf_pair(call: MethodCall) -> Estimates:
    """The reference's tracks ``x (B, K, N, 2)`` in ``[r, rdot]``, one per target, scored as
    unlabelled tracks (matched to the targets scan by scan like every other row of the plane)."""
    pair = int(call.spec.option("pair"))
    z, _, origin = pair_detections(call, pair)
    F, Q = cv_matrices(call.models.dt, float(call.spec.option("process_sd_mps2")), z.device)
    R = torch.diag(pair_deviations(call.sensing.detection_model, pair, z.device) ** 2)
    x, P, exists = known_association_kf(z, origin, call.alive.shape[1], F, Q, R, call.alive)
    return Estimates(x, exists, P, paired=False)


# ------------------------------------------------------------------ refusals and registration


def check_pair_sensing(spec, sensing) -> None:
    """Detections the kinds can not read, one line each naming the method and the fix."""
    where = f"method {spec.name!r} (kind {spec.kind})"
    model = sensing.detection_model
    if model is None:
        raise ConfigError(f"{where} reads detections, and this scenario makes none: add a detections: block (a "
                          "designed scenario) or use a multi-target scenario")
    comps = list(model.components)
    if "range" not in comps or not any(c in comps for c in RATE_COMPONENTS):
        raise ConfigError(f"{where} tracks one pair's bistatic range and range-rate; the detections measure "
                          f"{comps}: give detections of range and range_rate (noise.range_rate_mps in a multi-target "
                          "scenario) or range and doppler")
    pair = int(spec.option("pair"))
    if not 0 <= pair < model.n_pairs:
        raise ConfigError(f"{where}: pair {pair} is out of range: the detections have {model.n_pairs} "
                          f"transmitter-receiver pair(s), 0..{model.n_pairs - 1}; set option pair to one of them")
    if not sensing.illuminator_known:
        raise ConfigError(f"{where} reads one pair's detection list; here the detections are pooled per receiver "
                          "(illuminator_known: false): set illuminator_known true")
    try:
        if spec.kind == "smc_phd_pair":
            phd_settings(spec)
            if spec.option("labelling") != "none":
                label_settings(spec)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


PROBABILITY = dict(lo=0.5, hi=1.0 - 1e-12)
LABELLED = ReadWhen("labelling", ("gtda", "hungarian"))
"""The track labelling's options: unread with ``labelling: none``."""
GTDA = ReadWhen("labelling", ("gtda",))
"""The regret-matching game's options: read by GTDA only."""
PAIR = Option(0, int, 0, 1_000_000)
PROCESS_SD = Option(20.0, float, 0.0, 1.0e4)
OPTIONS = {
    "pair": PAIR,
    "particles_per_target": Option(4000, int, 10, 1_000_000),
    "particles_per_birth": Option(800, int, 10, 1_000_000),
    # adaptive: births only where the persistent PHD explains no detection, particles following their mass
    # (PHDSpec.adaptive_birth); every_detection: particles_per_birth on every detection (before issue 37)
    "births": Option("adaptive", str, choices=("adaptive", "every_detection")),
    "birth_particles_min": Option(100, int, 10, 1_000_000, read_when=ReadWhen("births", ("adaptive",))),
    "survival": Option(0.99, float, 1e-6, 1.0),
    "birth_rate": Option(0.05, float, 1e-9, 100.0),
    "process_sd_mps2": PROCESS_SD,
    "estimate_mass": Option(0.5, float, 1e-6, 1.0),
    "kmeans_iterations": Option(1, int, 0, 100),
    "phd_gate_probability": Option(0.999, float, **PROBABILITY),
    "labelling": Option("gtda", str, choices=("gtda", "hungarian", "none")),
    "label_gate_probability": Option(0.999, float, **PROBABILITY, read_when=LABELLED),
    "max_missed": Option(3, int, 0, 10_000, read_when=LABELLED),
    "confirm_m": Option(2, int, 1, 62, read_when=LABELLED), "confirm_n": Option(3, int, 1, 62, read_when=LABELLED),
    "forgetting": Option(0.9, float, 1e-6, 1.0, read_when=GTDA),
    "game_iterations": Option(50, int, 1, 100_000, read_when=GTDA),
    "conflict": Option(1.0, float, 1e-6, 1.0e6, read_when=GTDA),
    "alpha_scale": Option(2.0, float, 1.0, 1.0e6, read_when=GTDA),  # above 1: GameSpec refuses 1 itself
    "merge_scans": replace(COALESCENCE_OPTIONS["merge_scans"], read_when=LABELLED),
    "merge_probability": COALESCENCE_OPTIONS["merge_probability"],
}
register(MethodKind("smc_phd_pair", "detections", run_smc_phd_pair, OPTIONS, check_sensing=check_pair_sensing,
                    starts_tracks=True, space=pair_space, metrics=(Labelling(), PHDFigures(), Unlabelled()),
                    any_device=True,
                    description="SMC-PHD in one pair's bistatic plane [r, rdot] (Daniyan et al.; births around the "
                                "previous scan's detections no existing target explains, births: adaptive; "
                                "every_detection: on all of them), its estimates labelled by GTDA or the Hungarian "
                                "baseline, or unlabelled (labelling: none); scored in that plane (OSPA on bistatic "
                                "range); starts its own tracks"))
register(MethodKind("known_association_kf_pair", "detections", run_known_association_kf_pair,
                    {"pair": PAIR, "process_sd_mps2": PROCESS_SD}, check_sensing=check_pair_sensing,
                    initiation="association known", space=pair_space, any_device=True,
                    description="reference: a Kalman filter per target in one pair's bistatic plane on exactly its own "
                                "detections (reads their true origins), started at its first detection (births "
                                "known); scored in that plane"))
