"""Preparing a multi-target study (``kind: multitarget``, :mod:`.multitarget`) for the runner.

Takes a :class:`~.multitarget.MultiTargetScenario`; gives the runner's :class:`~.prepared.Setup`:
per case the targets flying CV (process noise drawn per run, straight lines, or designed
aircraft), seen through detections with the case's Pd and clutter (pooled per receiver when the
illuminator is unknown), the trackers through their registered kinds, the settings and
definitions ``results.json`` records. Every user error surfaces here, before anything is written.

This is the simulation study of Section IV of the S-MSJPDA paper: a few targets flying in parallel,
range + Doppler from every transmitter-receiver pair, trackers started at the truth plus noise.
Every draw of a block of runs (truth process noise, detections, clutter, the initiation offsets)
comes from a generator seeded by ``(seed, case, block)``; every method runs on whole blocks.
"""

from __future__ import annotations

import math

import torch

from ..config import to_dict
from ..errors import ConfigError
from ..measurements import SPEED_OF_LIGHT, MeasurementModel
from ..methods import Models, lists_read, method_kind
from ..motion import motion_model
from ..simulation.aircraft import fly_all
from ..simulation.products import DesignedTruth, SampledTruth, SensorSetup, check_pooled_clutter
from .case_bounds import case_bounds
from .definitions import multitarget_definitions
from .method_spec import MethodSpec
from .multitarget import MTMotionSpec, MultiTargetScenario
from .prepared import Case, LossRule, Setup, method_refusals, raise_refusals


def tracker_methods(sc: MultiTargetScenario) -> tuple[MethodSpec, ...]:
    """The study's trackers as :class:`~.method_spec.MethodSpec` with the tracker section's options."""
    out = []
    for m in sc.methods:
        options = {k: v for k, v in (("m_best", m.m_best or sc.tracker.m_best),
                                     ("gate_probability", sc.tracker.gate_probability),
                                     ("relaxation_iterations", sc.tracker.relaxation_iterations))
                   if k in method_kind(m.kind).options}
        out.append(MethodSpec(m.name, m.kind, options={**options, **m.options}))
    return tuple(out)


def detection_models(sc: MultiTargetScenario, geometry, motion) -> tuple[MeasurementModel, MeasurementModel]:
    """The detections' model (pair layout): bistatic range and Doppler, or range and range-rate
    where ``noise.range_rate_mps`` is given; and the model of detections from signals (range and
    Doppler always: what the signal chain measures; a range-rate deviation converted through the
    carrier, which must then be one for every transmitter)."""
    n = sc.noise
    doppler = MeasurementModel(geometry, ("range", "doppler"), (n.range_m, n.doppler_hz), motion.pos_idx, motion.vel_idx,
                               layout="pair")
    if n.range_rate_mps is None:
        return doppler, doppler
    model = MeasurementModel(geometry, ("range", "range_rate"), (n.range_m, n.range_rate_mps), motion.pos_idx,
                             motion.vel_idx, layout="pair")
    carriers = {t.carrier_hz for t in sc.geometry.transmitters}
    if sc.front_end is None or not any(c.signals for c in sc.cases):
        return model, model
    if len(carriers) > 1:
        raise ConfigError("noise.range_rate_mps with detections from signals needs one carrier for every transmitter "
                          "(the chain measures Doppler); give noise.doppler_hz instead")
    fc = carriers.pop()
    return model, MeasurementModel(geometry, ("range", "doppler"), (n.range_m, n.range_rate_mps * fc / SPEED_OF_LIGHT),
                                   motion.pos_idx, motion.vel_idx, layout="pair")


def prepare_multitarget(sc: MultiTargetScenario, device: str = "cpu") -> Setup:
    """The study as a runner :class:`~.prepared.Setup`: per case the targets flying CV (with
    process noise drawn per run, or on straight lines), seen through detections with the case's
    Pd and clutter (pooled per receiver when the illuminator is unknown). Straight flights also
    get the PCRB of each target (every run flies them)."""
    if device != "cpu":
        raise ConfigError("the multi-target trackers run on the CPU (their assignment step is NumPy/SciPy)")
    dims = sc.dimensions
    geometry = sc.geometry.build(dims)
    motion = motion_model(sc.motion.model, dims)
    q = sc.motion.q_per_axis(dims)
    model, signal_model = detection_models(sc, geometry, motion)
    models = Models(motion, model, sc.motion.dt_s, q, model.R(), torch.tensor(model.noise_std, dtype=torch.float64))
    if not sc.illuminator_known:
        for c in sc.cases:
            check_pooled_clutter(sc.case_settings(c)[1], model, f"case {c.name!r}")
    methods = tracker_methods(sc)
    kinds = {m.name: method_kind(m.kind) for m in methods}
    straight = sc.motion.truth == "straight"
    if sc.aircraft:  # designed flights, seen above min_altitude_m and within max_range_m (checked clear of sensors)
        flights = DesignedTruth(*fly_all(sc.aircraft, sc.scans, sc.motion.dt_s, model, sc.min_altitude_m,
                                         math.inf if sc.max_range_m is None else sc.max_range_m))
    cases, refusals = [], []
    for c in sc.cases:  # every target's whole flight must stay clear of the sensors
        pd, clutter, spacing = sc.case_settings(c)
        x0 = flights.x[0] if sc.aircraft else sc.initial_states_for(spacing)
        if not sc.aircraft:
            t = torch.arange(sc.scans, dtype=torch.float64) * sc.motion.dt_s
            nominal = torch.einsum("kij,tj->tki", motion.F(t), x0)  # (N, K, n), no noise
            if bool(model.near_sensor(nominal, 1000.0).any()):
                raise ConfigError(f"case {c.name!r}: a target passes within 1 km of a sensor")
        prior = c.prior or sc.prior
        P0 = prior.sd(dims)
        front_end = sc.front_end if c.signals else None
        sensing = SensorSetup(model, P0, detection_model=model if front_end is None else signal_model, pd=pd,
                              clutter=clutter, illuminator_known=sc.illuminator_known, front_end=front_end)
        alive = flights.alive if sc.aircraft else torch.ones(sc.scans, len(x0), dtype=torch.bool)
        bounds = None
        if sc.aircraft:
            truth = flights
        elif straight:
            truth = DesignedTruth(nominal.transpose(0, 1).contiguous(), alive)
            bounds = case_bounds(truth.x, alive, models, torch.diag(P0**2))
        else:
            truth = SampledTruth(x0, motion, sc.scans, sc.motion.dt_s, q)
        scored = alive & (torch.arange(sc.scans) >= sc.converged_from_scan)[:, None]
        refusals += method_refusals(methods, kinds, {}, alive, c.name, sensing)
        info = {"pd": pd, "clutter_per_scan": clutter.per_scan, "spacing_m": spacing, "prior": to_dict(prior),
                "reference_key": c.reference_key, "formation": not (sc.initial_states or sc.aircraft),
                "clutter_list": "sensor" if sc.illuminator_known else "receiver",
                "detections_from": "signals" if front_end is not None else "model"}
        names = [a.name for a in sc.aircraft] or [f"target {i + 1}" for i in range(len(x0))]
        # set figures average over every scan after convergence, also where no target lives (an
        # estimate there is false); with every target alive throughout, the scans where one is scored
        cases.append(Case(c.name, c.title or c.name, truth, sensing, alive, scored, names, info, bounds,
                          set_scans=torch.arange(sc.scans) >= sc.converged_from_scan))
    raise_refusals(refusals)
    definitions = multitarget_definitions(kinds.values(), straight, motion.dim_x)
    causal = {m.name: bool(kinds[m.name].causal(None)) for m in methods}
    return Setup(sc, models, cases, methods, kinds, {m.name: None for m in methods}, causal,
                 "per_block", (sc.set_metrics.c_m, sc.set_metrics.p), describe_multitarget(sc, model, methods),
                 definitions, geometry, loss=LossRule(sc.loss.successive_scans, sc.loss.gate_range_sd_m))


def describe_multitarget(sc: MultiTargetScenario, model: MeasurementModel, methods) -> dict:
    """Settings recorded beside the figures (``results.json``'s ``settings``)."""
    g = model.geometry
    out = {"dt_s": sc.motion.dt_s, "q": sc.motion.q, "scans": sc.scans, "state_dim": 2 * sc.dimensions,
           "targets": to_dict(sc.targets), "noise": sc.to_dict()["noise"], "pd": sc.pd, "clutter": to_dict(sc.clutter),
           "clutter_volume_m_hz": sc.clutter.volume,
           "prior": to_dict(sc.prior), "tracker": to_dict(sc.tracker), "loss": to_dict(sc.loss),
           "converged_from_scan": sc.converged_from_scan, "warmup_steps": sc.converged_from_scan, "sweep": sc.sweep,
           "block_runs": sc.block_runs, "set_metrics": to_dict(sc.set_metrics),
           "transmitters": [{"position_m": list(t.position_m), "carrier_hz": t.carrier_hz} for t in g.transmitters],
           "receivers": [list(r.position_m) for r in g.receivers],
           "methods": {m.name: {"kind": m.kind, "reads": method_kind(m.kind).reads, **m.options,
                                **({} if sc.illuminator_known or method_kind(m.kind).reads != "detections"
                                   else {"lists": lists_read(method_kind(m.kind))})} for m in methods}}
    if sc.dimensions == 3 or sc.initial_states or sc.motion != MTMotionSpec(sc.motion.dt_s, sc.motion.q) \
            or not sc.illuminator_known:
        out.update({"dimensions": sc.dimensions, "motion": to_dict(sc.motion), "illuminator_known": sc.illuminator_known,
                    "initial_states": [to_dict(t) for t in sc.initial_states]})
    if sc.aircraft:
        out.update({"aircraft": [a.name for a in sc.aircraft], "min_altitude_m": sc.min_altitude_m,
                    "max_range_m": sc.max_range_m})
    if sc.front_end is not None:
        fe = sc.front_end
        out["front_end"] = {**to_dict(fe), "map_shape": list(fe.map_shape), "range_bin_m": fe.signal.range_bin_m,
                            "doppler_bin_hz": fe.doppler_bin_hz, "samples_per_cpi": fe.signal.samples}
    return out
