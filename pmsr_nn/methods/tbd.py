"""Track-before-detect on the ``rd_maps`` product: the SMC multi-Bernoulli filters of the Remote
Sensing 2020 seed (:mod:`pmsr_nn.tbd`), and detect-then-track on the same maps.

One kind per filter the seed names, so that ``pmsr methods`` lists each and a scenario says which
it runs in one word (``kind: modified_icmb``) rather than through a combination of options; the
options are what varies within a filter:

* ``pmb``: the product update (the seed's PMB, Eq. 16: one update with the product of every map's
  likelihood ratio) with a modelled SNR (``snr_model_db``, one value for every map; null: the
  maps' true SNRs);
* ``icmb``: the iterated-corrector update, one map after another (Eqs. 26-27) in the ``order``
  (``ascending`` / ``descending`` / ``given``) of the SNRs it uses (modelled or true, as ``pmb``);
* ``modified_icmb``: the ICMB with the SNR of each map estimated online (the seed's proposal:
  the largest maximum-likelihood amplitude over the predicted particles, Eq. 25), which also
  orders the maps;
* ``detect_then_track``: each map thresholded (``detector``: OS-CFAR or the known-noise
  threshold, per-cell false-alarm probability ``pfa``), the detections tracked by the same filter
  with the standard detection likelihood (:mod:`pmsr_nn.tbd.detect`), maps in the ``order`` of
  their true SNRs.

Common options: the filter's detection ``threshold`` on the existence, ``survival``, ``birth_r``,
``prune``, the particle counts, the CV model's ``accel_sd_mps2``, ``roughening`` (Gordon's K
after each resampling; 0, the seed's filter, has none), ``ghost_rule`` (``shared``: a component
sharing some maps' cells with a stronger one is dropped; ``evidence``: unless the maps it shares
with none give it ``ghost_evidence`` nats of its own) and (map likelihoods) the
``subarea_half`` read around each state (null: the whole map). Defaults are the seed's, except
``snr_estimator``.

Every kind starts its own tracks: it returns the Bernoulli components as unpaired tracks in the
scenario's state (the planar CV state at the maps' altitude placed in the truth's position and
velocity columns, acceleration 0). A component keeps its label (its slot's life) across frames; a
track is confirmed by existence (above the threshold) and deleted by existence (below
``delete_existence``, by default the threshold itself). A component slot is reused after its
component died; a birth into a slot starts a new track. The per-frame extras below read the same
reported tracks, so the report's track-before-detect table and its set-metric table count the
same tracks. Per-frame extras for the Remote Sensing figures (read by the kinds' metric
:class:`~.kind_metrics.TBDFrames`): ``tbd_detected`` (some track reported), ``tbd_best_x`` (the
mean of the reported track of highest existence), ``tbd_best_r`` (the existence of the most
probable component, reported or not), ``tbd_snr_db``
(the SNR each map's update used) and ``tbd_particles``.

Random draws: the filter's from ``(seed, case, block, crc32(name))``, on the device of the maps
(the product's ``device``: its maps are drawn on the CPU and handed there), as every tensor of the
filter.
"""

from __future__ import annotations

import torch

from ..errors import ConfigError
from ..rng import seeded_generator
from ..tbd.detect import DetectSpec
from ..tbd.maps import power_ratio
from ..tbd.multibernoulli import MBOutput, MBSpec
from ..tbd.run import run_filter
from ..trackers.base import Estimates
from . import MethodCall, MethodKind, Option, method_stream, register
from .kind_metrics import TBDFrames

MAP_KINDS = ("pmb", "icmb", "modified_icmb")
"""Kinds whose likelihood is the maps' own (the others track detections of the maps)."""


def mb_spec(spec) -> MBSpec:
    """The filter's settings from a method's options (a one-line :class:`ConfigError` naming the method)."""
    o = spec.option
    kind = spec.kind
    update = "product" if kind == "pmb" else o("order")
    model = o("snr_model_db") if kind in ("pmb", "icmb") else None
    estimator = o("snr_estimator") if kind == "modified_icmb" else "max"
    try:
        return MBSpec(update=update, estimate_snr=kind == "modified_icmb", snr_estimator=estimator,
                      snr_model_db=None if model is None else (float(model),),
                      subarea_half=o("subarea_half") if kind in MAP_KINDS else 2,
                      particles_min=int(o("particles_min")), particles_max=int(o("particles_max")),
                      birth_particles=int(o("birth_particles")), birth_r=float(o("birth_r")),
                      survival=float(o("survival")), prune=float(o("prune")), threshold=float(o("threshold")),
                      accel_sd_mps2=float(o("accel_sd_mps2")), roughening=float(o("roughening")),
                      ghost_rule=o("ghost_rule"), ghost_evidence=float(o("ghost_evidence")))
    except ConfigError as exc:
        raise ConfigError(f"method {spec.name!r}: {exc}") from None


def detect_spec(spec) -> DetectSpec | None:
    if spec.kind != "detect_then_track":
        return None
    return DetectSpec(pfa=float(spec.option("pfa")), detector=spec.option("detector"))


def tracks_of(out: MBOutput, threshold: float, to_state, delete: float | None = None
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Unpaired tracks of the filter's output: ``x (B, K, M, n)``, ``exists (B, K, M)`` and the
    existence ``(B, K, M)``. A track is one life of a component slot (from the birth into it to
    the next birth into it: its label), confirmed at the first frame its existence is above
    ``threshold`` and reported from then on while its existence is above ``delete`` (None: the
    threshold, so reported exactly where above it); ``to_state`` maps CV means ``(..., 4)`` into
    the scenario's state."""
    B, K, n_slots = out.r.shape
    dev = out.r.device
    exists = out.r > threshold
    born = torch.nn.functional.one_hot(out.born, n_slots).to(torch.int64)  # (B, K, n_slots)
    if delete is not None and delete < threshold:
        seen = exists.to(torch.int64).cumsum(1)  # frames above the threshold so far, over the slot's lives
        before = torch.cat([seen.new_zeros(B, 1, n_slots), seen[:, :-1]], 1)
        at_birth = torch.where(born.bool(), before, torch.zeros_like(before)).cummax(1).values  # count when this life began
        exists = (seen > at_birth) & (out.r > delete)
    life = born.cumsum(1)  # (B, K, n_slots): how many births the slot had so far
    key = torch.arange(n_slots, device=dev) * (K + 1) + life  # (B, K, n_slots): one id per life of a slot
    L = n_slots * (K + 1)
    reported = life.new_zeros(B, L).scatter_reduce(1, key.flatten(1), exists.flatten(1).to(torch.int64), "amax")
    M = max(int(reported.sum(1).max()), 1)
    index = (reported.cumsum(1) - 1).gather(1, key.flatten(1)).view(B, K, n_slots)  # track of each (run, frame, slot)
    keep = reported.gather(1, key.flatten(1)).view(B, K, n_slots).bool() & (out.r > 0)
    b, k, q = torch.nonzero(keep, as_tuple=True)
    t = index[b, k, q]
    x = torch.zeros(B, K, M, 4, dtype=torch.float64, device=dev)
    x[b, k, t] = out.x[b, k, q]
    r = torch.zeros(B, K, M, dtype=torch.float64, device=dev)
    r[b, k, t] = out.r[b, k, q]
    reported_now = torch.zeros(B, K, M, dtype=torch.bool, device=dev)
    reported_now[b, k, t] = exists[b, k, q]
    return to_state(x), reported_now, r


def run_tbd(call: MethodCall) -> Estimates:
    """The kind's filter on the call's maps: unpaired tracks and the per-frame extras (module docstring)."""
    spec = call.spec
    scene = call.product.scene  # the case's, but for its frames where the product is a first slice (the warm-up's)
    mb = mb_spec(spec)
    g = seeded_generator(*call.seed, method_stream(spec.name), device=call.product.device)  # the maps' device
    out = run_filter(scene, mb, call.product, g, detect_spec(spec))
    n = call.models.motion.dim_x
    to_state = lambda cv: scene.from_cv(cv, n)
    x, exists, r = tracks_of(out, mb.threshold, to_state, spec.option("delete_existence"))
    # detected and its estimate from the reported tracks (the set metrics' own); the existence
    # curve stays the most probable component's, reported or not
    best_r = out.best(mb.threshold)[2]
    top = torch.where(exists, r, torch.full_like(r, -1.0)).argmax(-1)  # (B, K)
    best_x = x.gather(2, top[..., None, None].expand(*top.shape, 1, x.shape[-1]))[:, :, 0]
    extras = {"tbd_detected": exists.any(-1), "tbd_best_x": best_x, "tbd_best_r": best_r,
              "tbd_snr_db": out.snr_db, "tbd_particles": out.particles}
    return Estimates(x, exists, None, extras, paired=False, existence=r)


def describe(spec, scene) -> dict:
    """What the report says of a method's filter: its update, the SNR it uses, its sub-area and
    that sub-area's expected share of a target's energy (``power_ratio``; None for detections)."""
    mb = mb_spec(spec)
    maps = spec.kind in MAP_KINDS
    if spec.kind == "detect_then_track":
        update = "detect-then-track"
    else:
        update = mb.update
    if mb.estimate_snr:
        snr = f"estimated ({mb.snr_estimator})"
    elif mb.snr_model_db is None or not maps:
        snr = "true"
    else:
        snr = f"modelled {list(mb.snr_model_db)} dB"
    h = mb.subarea_half
    return {"update": update, "snr": snr, "subarea": ("full" if h is None else f"{2 * h + 1}x{2 * h + 1}") if maps else None,
            "power_ratio": power_ratio(h, scene.maps.lobe_cells) if maps else None}


def check_sensing(spec, sensing) -> None:
    """Refuses a scenario without maps, and settings the filter refuses or the maps can not hold."""
    scene = getattr(sensing, "rd_maps", None)
    if scene is None:
        raise ConfigError(f"method {spec.name!r} (kind {spec.kind}) reads range-Doppler maps, which this scenario does "
                          "not make: add an rd_maps section (snr_db, birth_box, maps; transmitters and receiver_m, or "
                          "the recipe's pairs)")
    mb = mb_spec(spec)
    try:
        detect_spec(spec)
    except ConfigError as exc:
        raise ConfigError(f"method {spec.name!r}: {exc}") from None
    try:
        grid = scene.grid
    except ConfigError:
        return  # the case's own check says why the maps can not be formed
    h = mb.subarea_half
    if spec.kind in MAP_KINDS and h is not None and (2 * h + 1 > grid.D or 2 * h + 1 > grid.U):
        raise ConfigError(f"method {spec.name!r}: sub-area {2 * h + 1}x{2 * h + 1} is larger than the maps "
                          f"({grid.D} Doppler x {grid.U} range cells); use subarea_half: null for the whole map")


PROBABILITY = dict(lo=1e-9, hi=1.0 - 1e-9)
COMMON = {
    "threshold": Option(0.5, float, 1e-6, 1.0 - 1e-6),
    "survival": Option(0.95, float, 1e-6, 1.0),
    "birth_r": Option(0.01, float, **PROBABILITY),
    "prune": Option(1e-3, float, 0.0, 0.5),
    "particles_min": Option(2000, int, 1, 10_000_000),
    "particles_max": Option(10_000, int, 1, 10_000_000),
    "birth_particles": Option(10_000, int, 1, 10_000_000),
    "accel_sd_mps2": Option(0.05, float, 0.0, 1.0e3),
    "roughening": Option(0.0, float, 0.0, 10.0),
    "delete_existence": Option(None, float, 0.0, 1.0, nullable=True, null="the threshold: reported where above it"),
    "ghost_rule": Option("shared", str, choices=("shared", "evidence")),
    "ghost_evidence": Option(3.0, float, -1.0e3, 1.0e3),
}
SUBAREA = {"subarea_half": Option(2, int, 0, 10_000, nullable=True, null="the whole map")}
SNR_MODEL = {"snr_model_db": Option(None, float, -100.0, 100.0, nullable=True, null="each map's true SNR")}
ORDER = {"order": Option("ascending", str, choices=("ascending", "descending", "given"))}
FRAMES = (TBDFrames(describe),)
"""What every kind reports beside the runner's figures: the Remote Sensing 2020 figures per frame."""

register(MethodKind("pmb", "rd_maps", run_tbd, {**SNR_MODEL, **SUBAREA, **COMMON}, check_sensing=check_sensing,
                    starts_tracks=True, metrics=FRAMES, any_device=True,
                    description="SMC multi-Bernoulli track-before-detect, product update of every map (PMB; Zeng et "
                                "al., Remote Sensing 2020), modelled or true SNR; starts its own tracks"))
register(MethodKind("icmb", "rd_maps", run_tbd, {**ORDER, **SNR_MODEL, **SUBAREA, **COMMON}, check_sensing=check_sensing,
                    starts_tracks=True, metrics=FRAMES, any_device=True,
                    description="SMC multi-Bernoulli track-before-detect, one map after another in SNR order (ICMB; "
                                "Zeng et al.), modelled or true SNR; starts its own tracks"))
register(MethodKind("modified_icmb", "rd_maps", run_tbd, {"order": Option("ascending", str, choices=("ascending",
                                                                                                      "descending")),
                                                          "snr_estimator": Option("bootstrap", str,
                                                                                  choices=("bootstrap", "max")),
                                                          **SUBAREA, **COMMON},
                    check_sensing=check_sensing, starts_tracks=True, metrics=FRAMES, any_device=True,
                    description="ICMB with each map's SNR estimated online, ordering the maps (the modified ICMB of "
                                "Zeng et al., Remote Sensing 2020); starts its own tracks"))
register(MethodKind("detect_then_track", "rd_maps", run_tbd,
                    {"pfa": Option(1e-4, float, 1e-12, 0.5), "detector": Option("os_cfar", str,
                                                                                choices=("os_cfar", "known_noise")),
                     **ORDER, **COMMON},
                    check_sensing=check_sensing, starts_tracks=True, metrics=FRAMES, any_device=True,
                    description="each map thresholded (OS-CFAR or the known-noise threshold at pfa per cell), the "
                                "detections tracked by the same multi-Bernoulli filter; starts its own tracks"))
