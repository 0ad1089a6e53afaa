"""Grid search for the classical methods' options set to ``tuned`` (a fair baseline).

A method whose ``q`` (EKF, UKF) or ``q_quiet`` / ``q_manoeuvre`` / ``stay`` (IMM) is ``tuned``
gets the value that tracks best on *training* data: ``tuning.tracks`` truth tracks drawn from
the training recipe (the simulator the learned trackers are trained on; generator stream
``(tuning.seed, TUNING_STREAM)``, apart from every evaluation draw), measured with the
scenario's fixed noise (outliers included) and started from the scenario's initiation prior.
Each method runs at every point of the product of its tuned options' grids, on all tracks at
once (points that differ only in process-noise intensities share one call: the tracks are
repeated and ``q`` is given per run), and the point with the lowest position RMSE after the
warm-up (Eq. 31: per-step RMSE over the tracks, averaged over steps ``warmup_steps..K-1``)
wins; ties go to the earlier point. A point whose filter fails
(:class:`~pmsr_nn.filters.gaussian.FilterError`) scores infinity.
The search is deterministic given the seed.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time

import torch

from ...errors import ConfigError
from ...filters.gaussian import FilterError, Gaussian
from ...methods import Models
from ...methods.single_target import PER_RUN_OPTIONS, run_single
from ...metrics import position_columns, squared_error
from ...rng import seeded_generator
from ...simulation.products import SensorSetup, Truth, make_streams
from ...simulation.recipe import TrackRecipe, load_recipe
from ...simulation.tracks import generate_tracks
from .method_spec import MethodSpec
from .schema import Scenario

TUNING_STREAM = 0x74756E65
"""Second seed word of the tuning tracks' generator ('tune'): never a case index."""

MAX_RUNS_PER_CALL = 500
"""Most runs (grid points x tracks) filtered in one call, unless one point's tracks are more (an
IMM's outputs for 500 runs of 1000 steps take about 0.2 GB; ``tuning.tracks`` is at most 500)."""


@dataclasses.dataclass
class TuningData:
    """Truth ``(B, K, n)``, measurements ``z (B, K, m)`` and initiation prior of the tuning tracks."""

    truth: torch.Tensor
    z: torch.Tensor
    prior: Gaussian
    recipe: str


def training_recipe(sc: Scenario, recipe: TrackRecipe) -> tuple[TrackRecipe, str]:
    """The recipe the tuning tracks come from and its label; it must share the scenario recipe's
    geometry and sampling interval (the filters run with the scenario's models)."""
    path = sc.tuning.recipe if sc.tuning.recipe is not None else sc.recipe
    train = load_recipe(sc.path(path)) if path else TrackRecipe()
    label = str(sc.path(path)) if path else "built-in FITEE 2023 CA recipe"
    if train.dim != 2:
        raise ConfigError(f"tuning.recipe {label}: the harness evaluates planar (dim 2) recipes")
    if train.geometry.build(2).to_dict() != recipe.geometry.build(2).to_dict():
        raise ConfigError(f"tuning.recipe {label}: its sensor geometry differs from the scenario recipe's")
    if train.motion.dt_s != recipe.motion.dt_s:
        raise ConfigError(f"tuning.recipe {label}: dt_s {train.motion.dt_s} differs from the scenario recipe's "
                          f"{recipe.motion.dt_s}")
    if sc.warmup_steps >= train.motion.steps:
        raise ConfigError(f"tuning.recipe {label}: tracks of {train.motion.steps} steps leave none after "
                          f"warmup_steps {sc.warmup_steps}")
    return train, label


def tuning_data(sc: Scenario, recipe: TrackRecipe, models: Models, prior_sd: torch.Tensor) -> TuningData:
    """Draw the tuning tracks (truth from the training recipe, measurements as in the scenario)."""
    train, label = training_recipe(sc, recipe)
    g = seeded_generator(sc.tuning.seed, TUNING_STREAM)
    batch, _ = generate_tracks(train, sc.tuning.tracks, g)
    truth = batch.states
    sensing = SensorSetup(models.model, prior_sd, sc.noise.range_outlier_prob, sc.noise.range_outlier_scale)
    alive = torch.ones(truth.shape[1], 1, dtype=torch.bool)
    streams = make_streams(sensing, Truth(truth[:, :, None], alive), g, g)  # noise, prior, outliers: one generator
    prior = Gaussian(streams.prior.x[:, 0], streams.prior.P[:, 0])
    return TuningData(truth, streams.z[:, 0], prior, label)


def _scores(spec: MethodSpec, points: list[dict], data: TuningData, models: Models, warmup: int) -> list[float]:
    """Position RMSE after the warm-up (Eq. 31, m) at each of ``points`` (which differ only in
    options of :data:`~pmsr_nn.methods.single_target.PER_RUN_OPTIONS`), in one call: the tracks repeated once per
    point, the options given per run. A failing call is retried point by point; a point whose
    filter fails scores infinity."""
    B, K = data.truth.shape[:2]
    reps = len(points)
    options = {**spec.options, **points[0]}  # numbers, for validation; per_run overrides them
    trial = dataclasses.replace(spec, options=options)
    per_run = {k: torch.tensor([p[k] for p in points], dtype=torch.float64).repeat_interleave(B)
               for k in points[0] if k in PER_RUN_OPTIONS}
    prior = Gaussian(data.prior.x.repeat(reps, 1), data.prior.P.repeat(reps, 1, 1))
    try:
        x = run_single(trial, data.z.repeat(reps, 1, 1), prior, models, None, (0, TUNING_STREAM), per_run).x
    except FilterError:
        if reps == 1:
            return [math.inf]
        return [s for p in points for s in _scores(spec, [p], data, models, warmup)]
    se = squared_error(x.view(reps, B, K, -1), data.truth, position_columns(x.shape[-1]))[..., warmup:]
    rmse = se.mean(1).sqrt().mean(-1)  # (reps,): per-step RMSE over the tracks, averaged over steps
    return [float(r) if math.isfinite(float(r)) else math.inf for r in rmse]


def score(spec: MethodSpec, point: dict, data: TuningData, models: Models, warmup: int) -> float:
    """Position RMSE after the warm-up (Eq. 31, m) of ``spec`` with ``point``'s options on the
    tuning tracks (infinity if the filter fails)."""
    return _scores(spec, [point], data, models, warmup)[0]


def grid_points(spec: MethodSpec, sc: Scenario) -> list[dict]:
    """Every combination of the tuned options' grid values (``{option: value}``), in grid order."""
    keys = spec.tuned()
    return [dict(zip(keys, values)) for values in itertools.product(*(sc.tuning.grid(k) for k in keys))]


def _calls(points: list[dict], tracks: int) -> list[list[int]]:
    """Indices of ``points`` run together: those that agree on every option not given per run
    (the IMM's ``stay``), at most ``MAX_RUNS_PER_CALL // tracks`` at a time (at least one)."""
    per_call = max(1, MAX_RUNS_PER_CALL // tracks)
    groups: dict[tuple, list[int]] = {}
    for i, p in enumerate(points):
        groups.setdefault(tuple((k, v) for k, v in p.items() if k not in PER_RUN_OPTIONS), []).append(i)
    return [idx[j:j + per_call] for idx in groups.values() for j in range(0, len(idx), per_call)]


def tune_method(spec: MethodSpec, sc: Scenario, data: TuningData, models: Models) -> tuple[MethodSpec, dict]:
    """The method with its tuned options chosen, and the search's record (grid, per-point RMSE,
    choice) for ``results.json``."""
    t0 = time.perf_counter()
    points = grid_points(spec, sc)
    rmses = [math.inf] * len(points)
    for idx in _calls(points, len(data.truth)):
        for i, r in zip(idx, _scores(spec, [points[i] for i in idx], data, models, sc.warmup_steps)):
            rmses[i] = r
    best = min(range(len(points)), key=lambda i: (rmses[i], i))
    if not math.isfinite(rmses[best]):
        raise ConfigError(f"method {spec.name!r}: the filter failed at every grid point during tuning")
    chosen = points[best]
    edge = [k for k in spec.tuned() if len(sc.tuning.grid(k)) > 1 and chosen[k] in (min(sc.tuning.grid(k)),
                                                                                    max(sc.tuning.grid(k)))]
    record = {"options": spec.tuned(), "grid": {k: list(sc.tuning.grid(k)) for k in spec.tuned()},
              "points": [{**p, "rmse_pos_m": r} for p, r in zip(points, rmses)],
              "chosen": chosen, "rmse_pos_m": rmses[best], "at_grid_edge": edge,
              "tracks": len(data.truth), "steps": int(data.truth.shape[1]), "seed": sc.tuning.seed,
              "recipe": data.recipe, "warmup_steps": sc.warmup_steps, "seconds": time.perf_counter() - t0}
    return dataclasses.replace(spec, options={**spec.options, **chosen}), record


def tune(sc: Scenario, recipe: TrackRecipe, models: Models, prior_sd: torch.Tensor) -> tuple[tuple[MethodSpec, ...], dict]:
    """Resolve every ``tuned`` option of ``sc``'s methods: the methods as run and the records
    (method name -> record). The tuning tracks are drawn once and shared by all methods."""
    data = tuning_data(sc, recipe, models, prior_sd)
    methods, records = [], {}
    with torch.no_grad():
        for spec in sc.methods:
            if spec.tuned():
                spec, records[spec.name] = tune_method(spec, sc, data, models)
            methods.append(spec)
    return tuple(methods), records
