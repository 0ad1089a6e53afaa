"""Preparing a designed scenario (:class:`~.schema.Scenario`) for the runner.

Takes a scenario (a recipe's geometry and motion model, designed flights per case, the methods
with their options) and the device; gives the runner's :class:`~.prepared.Setup`: every case's
flights flown and checked against the recipe's envelope and sensors, its scored scans, sensing
(measurement streams, detections, range-Doppler maps), PCRB curves (:mod:`.case_bounds`), the
methods loaded (a learned tracker's checkpoint) and their refusals of each case, tuned options
resolved (:mod:`.tuning`), and the settings and definitions ``results.json`` records. Every user
error surfaces here, before anything is written.

A scenario with a ``world`` section (:mod:`.world`) has its own sensors and CV motion instead of a
recipe: per case its targets (a formation or listed states flying CV, process noise drawn per run
or straight lines, or designed aircraft) are seen through the case's detections (Pd, clutter,
pooled per receiver when the illuminator is unknown, or from signals through the front end), the
trackers started at the truth plus a draw from the case's prior; straight flights get each
target's PCRB (every run flies them). Every draw of a block of runs (truth process noise,
detections, clutter, the initiation offsets) comes from a generator seeded by ``(seed, case,
block)``.
"""

from __future__ import annotations

import dataclasses
import math

import torch

from ...config import to_dict
from ...errors import ConfigError
from ...measurements import SPEED_OF_LIGHT, MeasurementModel
from ...methods import Models, lists_read, method_kind
from ...motion import motion_model
from ...simulation.aircraft import fly_all
from ...simulation.products import DesignedTruth, SampledTruth, SensorSetup, check_pooled_clutter
from ...simulation.recipe import TrackRecipe, load_recipe
from ...simulation.tracks import MEASUREMENT_COMPONENTS, build_models
from ...tbd.scene import build_scene
from .case_bounds import case_bounds, maps_bound, memory_bounds
from .definitions import designed_definitions, world_definitions
from .prepared import Case, Setup, device_refusals, method_refusals, raise_refusals, set_scans_after
from .schema import Scenario
from .trajectories import check_inside, design_trajectory
from .tuning import tune
from .world import CVMotionSpec


class LoadContext:
    """What a method kind's ``load`` may read: paths, device, the scenario's geometry and labels,
    and the detections' measurement model (None where the scenario makes no detections)."""

    def __init__(self, sc: Scenario, recipe: TrackRecipe, model: MeasurementModel, device: str,
                 detection_model: MeasurementModel | None = None):
        self.path, self.device = sc.path, device
        self.geometry = recipe.geometry.build(2).to_dict()
        self.labels, self.dt = list(model.labels), recipe.motion.dt_s
        self.detection_model = detection_model
        self.where = f"scenario {sc.name!r}"


def _lives(case, dt: float) -> tuple[int, list[tuple[int, int]]]:
    """Scans ``K`` of a case and each target's ``(first, end)`` scan (end exclusive)."""
    spans = []
    for t in case.flights():
        first = int(math.ceil(t.birth_s / dt - 1e-9))
        steps = int(math.floor((t.end_s - first * dt) / dt + 1e-9))
        spans.append((first, first + steps))
    K = max(e for _, e in spans)
    if getattr(case, "end_s", None) is not None:  # the case's scans go on after its last target ends
        K = max(K, int(math.floor(case.end_s / dt + 1e-9)))
    return K, spans


def design_case(c, recipe: TrackRecipe, ramp_s: float) -> tuple[torch.Tensor, torch.Tensor]:
    """True states ``(K, N, 6)`` (NaN where a target is not alive) and ``alive (K, N)`` of a case;
    every target's flight is checked against the recipe's envelope and sensors."""
    dt = recipe.motion.dt_s
    K, spans = _lives(c, dt)
    flights = c.flights()
    x = torch.full((K, len(flights), 6), float("nan"), dtype=torch.float64)
    alive = torch.zeros(K, len(flights), dtype=torch.bool)
    for i, (t, (k0, k1)) in enumerate(zip(flights, spans)):
        where = c.name if not c.targets else f"{c.name}/{t.name}"
        if k1 - k0 < 2:
            raise ConfigError(f"case {where!r}: the trajectory is empty ({t.end_s - t.birth_s:g} s at dt = {dt} s: "
                              f"{k1 - k0} scan(s), at least 2 needed)")
        truth = design_trajectory(t, recipe, ramp_s)[: k1 - k0]
        check_inside(truth, recipe, where)
        x[k0:k1, i], alive[k0:k1, i] = truth, True
    return x, alive


def _scored(alive: torch.Tensor, warmup: int, case: str, targets: list[str]) -> torch.Tensor:
    """``alive`` minus each target's first ``warmup`` scans (a one-line error if none is left)."""
    since_birth = torch.cumsum(alive.to(torch.int64), 0)
    scored = alive & (since_birth > warmup)
    short = [targets[i] for i in range(alive.shape[1]) if not bool(scored[:, i].any())]
    if short:
        which = f"case {case!r} has {int(alive.sum())} steps" if len(targets) == 1 else \
            f"case {case!r}: target(s) {short} live {[int(alive[:, targets.index(s)].sum()) for s in short]} steps"
        raise ConfigError(f"{which}; warmup_steps {warmup} leaves none to average")
    return scored


def _models(sc: Scenario, recipe: TrackRecipe) -> tuple[Models, MeasurementModel | None]:
    """The per-target stream models (the recipe's CA motion and q, the scenario's fixed noise) and,
    where the scenario makes detections, the detection model (pair layout)."""
    motion, nominal = build_models(recipe)
    noise = sc.noise.si()
    model = dataclasses.replace(nominal, noise_std=noise)
    noise_std = torch.tensor(noise, dtype=torch.float64)
    models = Models(motion, model, recipe.motion.dt_s, recipe.effective_motion().q_psd, model.R(), noise_std)
    detection_model = None
    if sc.detections is not None:
        by_name = dict(zip(MEASUREMENT_COMPONENTS, noise))
        comps = tuple(sc.detections.components)
        detection_model = MeasurementModel(model.geometry, comps, tuple(by_name[c] for c in comps), motion.pos_idx,
                                           motion.vel_idx, layout="pair")
    return models, detection_model


def case_maps(sc: Scenario, c, recipe: TrackRecipe, models: Models, sensing: SensorSetup, x: torch.Tensor,
              alive: torch.Tensor, targets: list[str]) -> tuple[SensorSetup, dict, list[str]]:
    """A case's range-Doppler maps (the scenario's ``rd_maps`` section with the case's overrides,
    :func:`~pmsr_nn.tbd.scene.build_scene`; frames are the case's scans): its sensing with them,
    what ``results.json`` records of them (``info["rd_maps"]``) and the refusals of maps that can
    not hold the case (one line each). A case without maps: its sensing as given, nothing else."""
    spec = sc.case_rd_maps(c)
    if spec is None:
        return sensing, {}, []
    m = models.motion
    index = (m.pos_idx[0], m.vel_idx[0], m.pos_idx[1], m.vel_idx[1])
    K = alive.shape[0]
    try:
        scene = build_scene(spec, recipe.geometry.build(2), K, models.dt, index)
    except ConfigError as exc:
        return sensing, {}, [f"case {c.name!r}: {exc}"]
    out = dataclasses.replace(sensing, rd_maps=scene)
    refusals = scene.check(x, alive, c.name, targets)
    present = alive.any(1)
    frame = spec.table_frame if spec.table_frame is not None else int(torch.nonzero(present)[-1]) + 1
    if frame > K:
        refusals.append(f"case {c.name!r}: rd_maps.table_frame {frame} is past the case's last frame ({K})")
    if refusals:
        return out, {}, refusals
    grid = scene.grid
    info = {"maps": list(scene.names), "snr_db": list(scene.snr_db), "map_cells": [grid.D, grid.U],
            "doppler_cell_hz": scene.maps.doppler_cell_hz, "range_cell_m": scene.maps.range_cell_m,
            "present": present.tolist(), "table_frame": frame,
            "bound_pos_m": maps_bound(scene, x, alive, models, sensing.prior_sd).tolist()}
    return out, {"rd_maps": info}, []


def prepare_designed(sc: Scenario, device: str = "cpu") -> Setup:
    """Resolve, design and check everything a designed scenario needs (every user error surfaces
    here, before any output is written)."""
    if sc.world is not None:
        return prepare_world(sc, device)
    recipe = load_recipe(sc.path(sc.recipe)) if sc.recipe else TrackRecipe()
    if recipe.dim != 2:
        raise ConfigError(f"scenario {sc.name!r}: the harness evaluates planar (dim 2) recipes")
    models, detection_model = _models(sc, recipe)
    prior_sd = recipe.initiation_prior_sd()
    kinds = {m.name: method_kind(m.kind) for m in sc.methods}
    context = LoadContext(sc, recipe, models.model, device, detection_model)
    resources = {m.name: kinds[m.name].load(m, context) if kinds[m.name].load else None for m in sc.methods}
    causal = {m.name: bool(kinds[m.name].causal(resources[m.name])) for m in sc.methods}
    det = sc.detections
    sensing = SensorSetup(models.model, prior_sd, sc.noise.range_outlier_prob, sc.noise.range_outlier_scale,
                          detection_model, det.pd if det else None, det.clutter if det else None,
                          illuminator_known=det.illuminator_known if det else True)
    if det is not None and not det.illuminator_known:
        check_pooled_clutter(det.clutter, detection_model, "detections")
    cases, refusals = [], []
    for c in sc.cases:
        x, alive = design_case(c, recipe, sc.ramp_s)
        targets = [t.name for t in c.flights()]
        scored = _scored(alive, sc.warmup_steps, c.name, targets)
        if detection_model is not None and bool(detection_model.near_sensor(x[alive], recipe.min_sensor_distance_m).any()):
            raise ConfigError(f"case {c.name!r}: a target passes within {recipe.min_sensor_distance_m} m of a sensor")
        case_sensing, maps_info, maps_refusals = case_maps(sc, c, recipe, models, sensing, x, alive, targets)
        refusals += maps_refusals
        refusals += method_refusals(sc.case_methods(c), kinds, resources, alive, c.name, case_sensing)
        refusals += device_refusals(sc.case_methods(c), kinds, case_sensing, device)
        if refusals:
            continue  # said once every case is checked; no bound is worth computing now
        # the PCRB is the recipe's measurement model's: a case only maps are formed of has none
        bounded = any(kinds[m.name].reads != "rd_maps" for m in sc.case_methods(c))
        bounds = case_bounds(x, alive, models, torch.diag(prior_sd**2)) if bounded else None
        mb = memory_bounds(x, alive, sc.methods, resources, causal, models)
        info = {"lives": [{"name": t.name, "first_scan": int(k0), "end_scan": int(k1)}
                            for t, (k0, k1) in zip(c.flights(), _lives(c, models.dt)[1])], **maps_info}
        cases.append(Case(c.name, c.title or c.name, DesignedTruth(x, alive), case_sensing, alive, scored, targets, info,
                          bounds, mb, methods=tuple(c.methods), set_scans=set_scans_after(alive.shape[0], sc.warmup_steps)))
    raise_refusals(refusals)
    methods, tuning = sc.methods, {}
    if any(m.tuned() for m in sc.methods):  # last: the slowest check, after every quick one
        methods, tuning = tune(sc, recipe, models, prior_sd)
    settings = describe_designed(sc, recipe, models, prior_sd, tuning, detection_model)
    definitions = designed_definitions(sc.rd_maps is not None)
    return Setup(sc, models, cases, methods, kinds, resources, causal, sc.random_streams,
                 (sc.set_metrics.c_m, sc.set_metrics.p), settings, definitions, recipe.geometry.build(2),
                 divergence_m=sc.divergence_m, tuning=tuning, recipe=recipe, prior_sd=prior_sd, device=str(device))


def describe_designed(sc: Scenario, recipe: TrackRecipe, models: Models, prior_sd: torch.Tensor, tuning: dict,
                      detection_model: MeasurementModel | None) -> dict:
    """Settings recorded beside the figures (``results.json``'s ``settings``)."""
    out = {"recipe": str(sc.path(sc.recipe)) if sc.recipe else "built-in FITEE 2023 CA recipe", "variant": recipe.variant,
           "dt_s": recipe.motion.dt_s, "q_psd": models.q,
           "noise": {"range_m": sc.noise.range_m, "range_rate_mps": sc.noise.range_rate_mps,
                     "azimuth_deg": sc.noise.azimuth_deg,
                     **({"range_outlier_prob": sc.noise.range_outlier_prob,
                         "range_outlier_scale": sc.noise.range_outlier_scale} if sc.noise.has_outliers else {})},
           "measurement_components": list(MEASUREMENT_COMPONENTS), "prior_sd": prior_sd.tolist(),
           "prior": "per run and target: mean = truth at its birth + a draw from N(0, P0), P0 = diag(prior_sd^2); the "
                    "PCRB uses P0",
           "warmup_steps": sc.warmup_steps, "divergence_m": sc.divergence_m, "block_runs": sc.block_runs,
           "methods": {m.name: {"kind": m.kind, "reads": method_kind(m.kind).reads,
                                **({"checkpoint": str(sc.path(m.checkpoint))} if m.checkpoint else {}),
                                **m.options, **({"tuning": tuning[m.name]} if m.name in tuning else {})}
                       for m in sc.methods}}
    if detection_model is not None:
        d = sc.detections
        lo, ext = d.clutter.box(d.components)
        out["detections"] = {"pd": d.pd, "components": list(d.components), "clutter_per_scan": d.clutter.per_scan,
                             "clutter_model": d.clutter.model, "clutter_box_si": [[a, a + e] for a, e in zip(lo, ext)],
                             "sensors": detection_model.n_pairs}
        if not d.illuminator_known:  # a single-frequency network: which list each detection reader takes
            out["detections"].update({"illuminator_known": False, "receivers": len(detection_model.geometry.receivers)})
            for m in sc.methods:
                if method_kind(m.kind).reads == "detections":
                    out["methods"][m.name]["lists"] = lists_read(method_kind(m.kind))
    if sc.random_streams != "per_block" or any(len(c.flights()) > 1 for c in sc.cases):
        out["random_streams"] = sc.random_streams
        out["set_metrics"] = {"c_m": sc.set_metrics.c_m, "p": sc.set_metrics.p}
    if sc.rd_maps is not None:  # the maps' section as given (each case's overrides are in its own results)
        out["rd_maps"] = to_dict(sc.rd_maps)
        out["set_metrics"] = {"c_m": sc.set_metrics.c_m, "p": sc.set_metrics.p}
    return out


def world_models(sc: Scenario) -> tuple[Models, object]:
    """A world scenario's models (its CV motion and q, the detections' pair model with the
    scenario's noise of their components) and the sensors' geometry."""
    w = sc.world
    geometry = w.geometry.build(w.dimensions)
    motion = motion_model(w.motion.model, w.dimensions)
    comps = tuple(sc.detections.components)
    model = MeasurementModel(geometry, comps, sc.noise.of(comps), motion.pos_idx, motion.vel_idx, layout="pair")
    models = Models(motion, model, w.motion.dt_s, w.motion.q_per_axis(w.dimensions), model.R(),
                    torch.tensor(model.noise_std, dtype=torch.float64))
    return models, geometry


def signal_model(sc: Scenario, model: MeasurementModel) -> MeasurementModel:
    """The model of detections from signals: range and Doppler (what the chain measures), a
    range-rate deviation converted through the carrier (then one for every transmitter)."""
    if "range_rate" not in model.components:
        return model
    carriers = {t.carrier_hz for t in sc.world.geometry.transmitters}
    if len(carriers) > 1:
        raise ConfigError("noise.range_rate_mps with detections from signals needs one carrier for every transmitter "
                          "(the chain measures Doppler); give components [range, doppler] and noise.doppler_hz instead")
    sd = sc.noise.range_rate_mps * carriers.pop() / SPEED_OF_LIGHT
    return MeasurementModel(model.geometry, ("range", "doppler"), (sc.noise.range_m, sd), model.pos_idx, model.vel_idx,
                            layout="pair")


def world_truth(sc: Scenario, c, models: Models, P0: torch.Tensor):
    """A world case's truth, ``alive (K, N)``, target names and bounds (straight flights only):
    designed aircraft (seen above ``min_altitude_m``, within ``max_range_m``), or a formation /
    listed states flying CV (clear of the sensors), straight or with process noise per run."""
    w, motion, model = sc.world, models.motion, models.model
    K = w.scans
    if c.aircraft:
        truth = DesignedTruth(*fly_all(c.aircraft, K, w.motion.dt_s, model, w.min_altitude_m,
                                       math.inf if w.max_range_m is None else w.max_range_m))
        return truth, truth.alive, [a.name for a in c.aircraft], None
    x0 = c.formation.initial_states() if c.formation else \
        torch.tensor([t.state() for t in c.states], dtype=torch.float64)
    t = torch.arange(K, dtype=torch.float64) * w.motion.dt_s
    nominal = torch.einsum("kij,tj->tki", motion.F(t), x0)  # (N, K, n), no noise
    if bool(model.near_sensor(nominal, 1000.0).any()):
        raise ConfigError(f"case {c.name!r}: a target passes within 1 km of a sensor")
    alive = torch.ones(K, len(x0), dtype=torch.bool)
    names = [f"target {i + 1}" for i in range(len(x0))]
    if w.motion.truth == "straight":
        truth = DesignedTruth(nominal.transpose(0, 1).contiguous(), alive)
        return truth, alive, names, case_bounds(truth.x, alive, models, torch.diag(P0**2))
    return SampledTruth(x0, motion, K, w.motion.dt_s, models.q), alive, names, None


def prepare_world(sc: Scenario, device: str = "cpu") -> Setup:
    """A world scenario as a runner :class:`~.prepared.Setup` (see the module's docstring)."""
    w = sc.world
    models, geometry = world_models(sc)
    kinds = {m.name: method_kind(m.kind) for m in sc.methods}
    cases, refusals = [], []
    for c in sc.cases:
        det = sc.case_detections(c)
        if not det.illuminator_known:
            check_pooled_clutter(det.clutter, models.model, f"case {c.name!r}")
        prior = c.prior or w.prior
        P0 = prior.sd(w.dimensions)
        truth, alive, names, bounds = world_truth(sc, c, models, P0)
        detection_model = models.model if det.front_end is None else signal_model(sc, models.model)
        sensing = SensorSetup(models.model, P0, detection_model=detection_model, pd=det.pd, clutter=det.clutter,
                              illuminator_known=det.illuminator_known, front_end=det.front_end)
        scored = _scored(alive, sc.warmup_steps, c.name, names)
        refusals += method_refusals(sc.case_methods(c), kinds, {}, alive, c.name, sensing)
        refusals += device_refusals(sc.case_methods(c), kinds, sensing, device)
        info = {"pd": det.pd, "clutter_per_scan": det.clutter.per_scan,
                "spacing_m": c.formation.spacing_m if c.formation else None, "prior": to_dict(prior),
                "reference_key": c.reference_key, "formation": c.formation is not None,
                "clutter_list": "sensor" if det.illuminator_known else "receiver",
                "detections_from": "signals" if det.front_end is not None else "model"}
        cases.append(Case(c.name, c.title or c.name, truth, sensing, alive, scored, names, info, bounds,
                          methods=tuple(c.methods), set_scans=set_scans_after(w.scans, sc.warmup_steps)))
    raise_refusals(refusals)
    straight = w.motion.truth == "straight" and not any(c.aircraft for c in sc.cases)
    definitions = world_definitions(kinds.values(), straight, models.motion.dim_x)
    causal = {m.name: bool(kinds[m.name].causal(None)) for m in sc.methods}
    return Setup(sc, models, cases, sc.methods, kinds, {m.name: None for m in sc.methods}, causal, "per_block",
                 (sc.set_metrics.c_m, sc.set_metrics.p), describe_world(sc, models.model), definitions, geometry,
                 loss=sc.loss, divergence_m=sc.divergence_m, device=str(device))


def _jpda_options(m) -> dict:
    """The JPDA settings of a method's kind (m best events, gate, relaxation iterations) at their
    defaults, recorded beside its options (the report quotes them)."""
    kind = method_kind(m.kind)
    return {k: kind.options[k].default for k in ("m_best", "gate_probability", "relaxation_iterations")
            if k in kind.options}


def describe_world(sc: Scenario, model: MeasurementModel) -> dict:
    """A world scenario's settings recorded beside the figures (``results.json``'s ``settings``)."""
    w, d, g = sc.world, sc.detections, model.geometry
    names = {"range": "range_m", "doppler": "doppler_hz", "range_rate": "range_rate_mps", "azimuth": "azimuth_deg"}
    noise = {names[c]: getattr(sc.noise, names[c]) for c in d.components}  # the deviations of what is measured
    out = {"dt_s": w.motion.dt_s, "q": w.motion.q, "scans": w.scans, "state_dim": 2 * w.dimensions,
           "noise": noise, "pd": d.pd, "components": list(d.components), "clutter": to_dict(d.clutter),
           "clutter_volume_m_hz": d.clutter.volume, "prior": to_dict(w.prior),
           "loss": None if sc.loss is None else to_dict(sc.loss), "warmup_steps": sc.warmup_steps, "sweep": sc.sweep,
           "block_runs": sc.block_runs, "set_metrics": to_dict(sc.set_metrics),
           "transmitters": [{"position_m": list(t.position_m), "carrier_hz": t.carrier_hz} for t in g.transmitters],
           "receivers": [list(r.position_m) for r in g.receivers],
           "methods": {m.name: {"kind": m.kind, "reads": method_kind(m.kind).reads, **_jpda_options(m), **m.options,
                                **({} if d.illuminator_known else {"lists": lists_read(method_kind(m.kind))})}
                       for m in sc.methods}}
    if w.dimensions == 3 or w.motion != CVMotionSpec(w.motion.dt_s, w.motion.q) or not d.illuminator_known:
        out.update({"dimensions": w.dimensions, "motion": to_dict(w.motion), "illuminator_known": d.illuminator_known})
    aircraft = list(dict.fromkeys(a.name for c in sc.cases for a in c.aircraft))
    if aircraft:
        out.update({"aircraft": aircraft, "min_altitude_m": w.min_altitude_m, "max_range_m": w.max_range_m})
    if d.front_end is not None:
        fe = d.front_end
        out["front_end"] = {**to_dict(fe), "map_shape": list(fe.map_shape), "range_bin_m": fe.signal.range_bin_m,
                            "doppler_bin_hz": fe.doppler_bin_hz, "samples_per_cpi": fe.signal.samples}
    return out
