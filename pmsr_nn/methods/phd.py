"""SMC-PHD with track labelling on the detections: the multi-sensor Cartesian SMC-PHD filter
(:mod:`pmsr_nn.trackers.phd_cartesian`) over every pair, its estimates labelled by GTDA or the
Hungarian baseline (:func:`pmsr_nn.trackers.labelling.label_tracks`).

Kind ``smc_phd`` reads the per-pair detections (also where the scenario pools them per receiver:
the filter is then told each detection's illuminator). Nobody hands it the births: the PHD births
targets from position fixes of the previous scan's detections, which needs (bistatic range,
azimuth) in 2-D (:func:`check_sensing` refuses other detection models). The labelling confirms a
new track once it took an estimate in ``confirm_m`` of its first ``confirm_n`` scans and ends one
that missed more than ``max_missed`` scans in a row (the defaults are evaluate/daniyan_smcphd.yaml's);
with ``merge_scans`` (default null: none), two labels whose positions and velocities agree for that
many scans hold one drone and the younger ends (the coalescence test of issue 55's duplicate-free
management, :mod:`pmsr_nn.trackers.coalescence`); the result is unpaired tracks, scored as tracks.

The PHD uses the case's Pd and each pair's clutter intensity (the simulated clutter rate over the
clutter box's volume in (m, m/s or Hz, rad), floored as the PMHT's); its motion model is the
scenario's, with process noise ``q`` (null: the recipe's). The labelling predicts tracks with the
same model and gates them on position (its state is the motion model's, positions first).

Random draws: the filter's from ``(seed, case, block, crc32(name))``, the labelling's from the
same words plus 1, so runs are reproducible and shards merge bit for bit.
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from ..rng import seeded_generator
from ..trackers.base import Estimates
from ..trackers.gtda import GameSpec
from ..trackers.labelling import LabelSpec, label_tracks
from ..trackers.phd_cartesian import CartesianPHD, CartesianPHDSpec, check_model
from . import MIN_CLUTTER_PER_SCAN, MethodCall, MethodKind, Option, method_stream, register
from .kind_metrics import Labelling, PHDFigures
from .track_management import COALESCENCE_OPTIONS, coalescence


def clutter_intensity(sensing) -> float:
    """Expected clutter per scan and unit of one pair's measurement space (``SensorSetup``), floored."""
    clutter = sensing.pair_clutter()
    return max(clutter.per_scan, MIN_CLUTTER_PER_SCAN) / clutter.volume_of(sensing.detection_model.components)


def phd_spec(spec, sensing) -> CartesianPHDSpec:
    """The filter's settings from a method's options (``cluster_sd_m`` null: the range deviation)."""
    o = spec.option
    model = sensing.detection_model
    sd = o("cluster_sd_m")
    return CartesianPHDSpec(
        particles_per_target=int(o("particles_per_target")), particles_per_birth=int(o("particles_per_birth")),
        survival=float(o("survival")), birth_rate=float(o("birth_rate")),
        birth_velocity_sd_mps=float(o("birth_velocity_sd_mps")), estimate_mass=float(o("estimate_mass")),
        cluster_sd_m=float(model.noise_std[model.components.index("range")]) if sd is None else float(sd),
        regularisation=float(o("regularisation")))


def label_spec(spec) -> LabelSpec:
    """The labelling's settings from a method's options (the game's: evaluate/daniyan_smcphd.yaml's, the defaults)."""
    o = spec.option
    return LabelSpec(method=o("labelling"), gate_probability=float(o("label_gate_probability")),
                     max_missed=int(o("max_missed")), confirm_m=int(o("confirm_m")), confirm_n=int(o("confirm_n")),
                     game=GameSpec(), coalescence=coalescence(o))


def make_filter(call: MethodCall) -> CartesianPHD:
    """The call's SMC-PHD filter: the method's settings, the case's Pd and clutter, the scenario's motion model."""
    spec, m, s = call.spec, call.models, call.sensing
    q = m.q if spec.option("q") is None else float(spec.option("q"))
    model = s.detection_model
    return CartesianPHD(phd_spec(spec, s), m.motion, m.dt, q, model, s.pd, [clutter_intensity(s)] * model.n_pairs,
                        s.prior_sd)


def run_smc_phd(call: MethodCall) -> Estimates:
    """The filter on the call's per-pair detections, its estimates labelled: unpaired tracks ``x (B, K, tracks, n)``
    in the motion model's state; extras of the labelling and the PHD's ``phd_expected (B, K)`` (its
    integral after each scan's update) and ``phd_particles (B, K)``."""
    spec, m = call.spec, call.models
    phd = make_filter(call)
    det = call.product.scans
    dev = det.z.device  # the draws too: a generator on the device of the tensors it fills
    est = phd.run(det.z, det.valid, seeded_generator(*call.seed, method_stream(spec.name), device=dev))
    # the labelling gates on the first two state entries: positions first, the rest after
    n = m.motion.dim_x
    pos = list(m.motion.pos_idx)
    perm = torch.tensor(pos + [i for i in range(n) if i not in pos], device=dev)
    back = torch.argsort(perm)
    square = lambda P, idx: P[..., idx, :][..., idx]
    merge_idx = [perm.tolist().index(i) for i in (*pos, *m.motion.vel_idx)]  # the coalescence test's: position, velocity
    lab = label_tracks(est.x[..., perm], square(est.P, perm), est.exists, square(phd.F, perm), square(phd.Q, perm),
                       label_spec(spec), seeded_generator(*call.seed, method_stream(spec.name), 1, device=dev),
                       merge_idx)
    extras = {**lab.extras, "phd_expected": est.expected, "phd_particles": est.particles}
    return Estimates(lab.x[..., back], lab.exists, square(lab.P, back), extras, paired=False)


def check_sensing(spec, sensing) -> None:
    """Detections the PHD can not birth targets from, settings the filter or labelling refuse (one line each)."""
    try:
        check_model(sensing.detection_model, f"kind {spec.kind}")
        phd_spec(spec, sensing)
        label_spec(spec)
    except ConfigError as exc:
        raise ConfigError(f"method {spec.name!r}: {exc}") from None


PROBABILITY = dict(lo=0.5, hi=1.0 - 1e-12)
OPTIONS = {
    "particles_per_target": Option(2000, int, 10, 1_000_000),
    "particles_per_birth": Option(200, int, 10, 1_000_000),
    "birth_rate": Option(0.05, float, 1e-9, 100.0),
    "survival": Option(0.99, float, 1e-6, 1.0),
    "q": Option(None, float, 0.0, 1.0e6, nullable=True, null="the recipe's q"),
    "birth_velocity_sd_mps": Option(20.0, float, 1e-3, 1e5),
    "regularisation": Option(0.5, float, 0.0, 10.0),
    "estimate_mass": Option(0.5, float, 1e-6, 1.0),
    "cluster_sd_m": Option(None, float, 1e-3, 1e6, nullable=True, null="the detections' range deviation"),
    "labelling": Option("gtda", str, choices=("gtda", "hungarian")),
    "confirm_m": Option(2, int, 1, 62), "confirm_n": Option(3, int, 1, 62),
    "max_missed": Option(3, int, 0, 10_000),
    "label_gate_probability": Option(0.999, float, **PROBABILITY),
    **COALESCENCE_OPTIONS,
}
register(MethodKind("smc_phd", "detections", run_smc_phd, OPTIONS, check_sensing=check_sensing, starts_tracks=True,
                    metrics=(Labelling(), PHDFigures()), any_device=True,
                    description="multi-sensor SMC-PHD in Cartesian state (iterated corrector over the pairs, births "
                                "from position fixes) with GTDA or Hungarian track labelling (Daniyan et al.); "
                                "starts its own tracks"))
