"""Run a scenario: every method on the same Monte Carlo draws, in blocks, shardable.

One runner for every scenario. A prepared :class:`Setup` holds cases (:class:`Case`: a truth
source with the targets' births and deaths, how it is sensed, its bounds) and methods (a
:class:`~.scenario.MethodSpec` each, run through its registered kind, :mod:`pmsr_nn.methods`).
Per case and block of ``block_runs`` runs the runner draws the truth, makes each sensor product
the methods read (:mod:`pmsr_nn.simulation.products`), calls every method on the whole block and
keeps the block's sums (:mod:`.scoring`).

Estimate spaces: a kind whose estimates are not the scenario's state declares the space they live
in (``MethodKind.space``, an :class:`~pmsr_nn.methods.EstimateSpace`: one pair's bistatic range
and range-rate, :mod:`pmsr_nn.methods.phd_pair`). :func:`score` then reads the block's truth
projected into that space (:func:`truth_in`, once per block and space) and scores the space's
"position" and "velocity" columns through the same set-metric path as every other row; the row
records its ``space`` and the report marks it, so a range-only OSPA is never read as a Cartesian one.

Random streams: with ``per_block`` (the default, and the only choice of the older studies) one
generator seeded by ``(seed, case, block)`` gives the truth, then the product, then the initiation
prior. With ``per_product`` each product has its own generator ``(seed, case, block, stream)``
and the initiation prior one more, ``(seed, case, block, INIT_STREAM)``, shared by all products:
every method starts from the same tracks, and adding a method of another product changes no
other method's draws. A method that draws (the particle filter) has ``(seed, case, block,
crc32(name))``. A block's numbers therefore do not depend on which other blocks run beside it: a
shard ``I/N`` runs a contiguous slice of the blocks, and :func:`finalise` reduces the blocks in
order, which is why merged shards give the unsharded figures bit for bit.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from .. import interrupts
from ..bounds import finite_memory_pcrb, pcrb
from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..methods import MethodCall, MethodKind, Models, method_kind
from ..rng import seeded_generator
from ..simulation.products import DesignedTruth, PRODUCTS, SampledTruth, SensorSetup, Truth
from ..simulation.recipe import TrackRecipe, load_recipe
from ..simulation.tracks import MEASUREMENT_COMPONENTS, build_models
from . import scoring
from .scenario import MethodSpec, Scenario
from .seeds import comparisons, summarise_seeds
from .trajectories import check_inside, design_trajectory

INIT_STREAM = 0x696E6974
"""Last seed word of the initiation prior's generator under ``random_streams: per_product`` ('init')."""

FRONT_END = "@front_end"
"""Key of a signal chain's sums and examples in :class:`BlockSums` (beside the methods')."""


@dataclass
class Bounds:
    """PCRB curves of a designed case, each ``(K, N)`` numpy (NaN where a target is not alive):
    filtering and smoothing position / velocity RMSE bounds under the recipe's q, and the
    position bounds with q = 0 (the designed flights have no process noise)."""

    pos: np.ndarray
    vel: np.ndarray
    smoothing_pos: np.ndarray
    smoothing_vel: np.ndarray
    q0_pos: np.ndarray
    q0_smoothing_pos: np.ndarray


@dataclass
class Case:
    """A case ready to run. ``truth`` draws the true states of a block; ``alive (K, N)`` and
    ``scored (K, N)`` (alive and past the target's warm-up) say where each target counts;
    ``info`` is recorded beside the figures (the case's settings); ``bounds`` and, per causal
    learned method, ``memory_bounds`` (``name -> (scans read, (K, N) curve)``) exist for designed
    flights only."""

    name: str
    title: str
    truth: DesignedTruth | SampledTruth
    sensing: SensorSetup
    alive: torch.Tensor
    scored: torch.Tensor
    targets: list[str]
    info: dict = field(default_factory=dict)
    bounds: Bounds | None = None
    memory_bounds: dict = field(default_factory=dict)
    set_scans: torch.Tensor | None = None  # (K,) the scans set metrics average over (None: some target scored)
    methods: tuple[str, ...] = ()  # the methods the case runs (empty: every method of the scenario)

    def runs(self, spec) -> bool:
        """Whether the case runs method ``spec`` (a case may name the methods it runs)."""
        return not self.methods or spec.name in self.methods

    @property
    def set_scan_mask(self) -> torch.Tensor:
        """``(K,)`` the scans the set metrics (OSPA, GOSPA, cardinality) average over: ``set_scans``,
        or else the scans where some target is scored."""
        return self.scored.any(1) if self.set_scans is None else self.set_scans

    @property
    def steps(self) -> int:
        return self.alive.shape[0]

    @property
    def multi_target(self) -> bool:
        return self.alive.shape[1] > 1


@dataclass
class LossRule:
    """The S-MSJPDA paper's track-loss rule (:func:`~pmsr_nn.metrics.track_loss`)."""

    successive_scans: int = 4
    gate_range_sd_m: float = 5000.0


@dataclass
class Setup:
    """Everything a scenario run needs, resolved and checked before anything is written.

    ``scenario`` is the scenario as given (its ``to_dict`` names a shard's origin); ``methods``
    are its methods with tuned options resolved (``tuning``: the grid searches,
    :func:`~.tuning.tune`); ``kinds`` and ``resources`` their registered kinds and what each
    kind's ``load`` prepared (a learned method's tracker); ``settings`` and ``definitions`` go into
    ``results.json``; ``geometry`` draws the sensors in the figures.
    """

    scenario: object
    models: Models
    cases: list[Case]
    methods: tuple[MethodSpec, ...]
    kinds: dict[str, MethodKind]
    resources: dict
    causal: dict[str, bool]
    random_streams: str
    set_metric: tuple[float, float]
    settings: dict
    definitions: dict
    geometry: object
    loss: LossRule | None = None
    divergence_m: float | None = None
    tuning: dict = field(default_factory=dict)
    recipe: TrackRecipe | None = None
    prior_sd: torch.Tensor | None = None
    warm: set = field(default_factory=set)  # the methods called once (untimed) by run_blocks so far
    spaces: dict = field(default_factory=dict)  # (case, method) -> EstimateSpace or None (method_space)

    @property
    def products(self) -> list[str]:
        """Product kinds the methods read, in registration order."""
        reads = {k.reads for k in self.kinds.values()}
        return [p for p in PRODUCTS if p in reads]


def parse_shard(text: str) -> tuple[int, int]:
    """``"I/N"`` (1-based) -> ``(I, N)``, with a one-line error for anything else."""
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise ConfigError(f"shard must look like I/N (e.g. 1/4), got {text!r}") from None
    if not 1 <= i <= n:
        raise ConfigError(f"shard {text}: need 1 <= I <= N")
    return i, n


def shard_blocks(n_blocks: int, shard: tuple[int, int]) -> range:
    """The contiguous blocks shard ``(I, N)`` runs."""
    i, n = shard
    if n > n_blocks:
        raise ConfigError(f"{n} shards but only {n_blocks} block(s) of Monte Carlo runs; use at most {n_blocks} "
                          "shards, more runs, or a smaller block_runs")
    return range((i - 1) * n_blocks // n, i * n_blocks // n)


# ------------------------------------------------------------------ preparing a designed scenario


class _Context:
    """What a method kind's ``load`` may read: paths, device, the scenario's geometry and labels."""

    def __init__(self, sc: Scenario, recipe: TrackRecipe, model: MeasurementModel, device: str):
        self.path, self.device = sc.path, device
        self.geometry = recipe.geometry.build(2).to_dict()
        self.labels, self.dt = list(model.labels), recipe.motion.dt_s
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


def _per_target(x: torch.Tensor, alive: torch.Tensor, fn) -> list[tuple[int, int, object]]:
    """``fn(truth (1, L, n))`` for each target over its life: ``[(first, end, result), ...]``."""
    out = []
    for t in range(alive.shape[1]):
        on = torch.nonzero(alive[:, t]).flatten()
        k0, k1 = int(on[0]), int(on[-1]) + 1
        out.append((k0, k1, fn(x[k0:k1, t][None])))
    return out


def _curves(parts, K: int, get) -> np.ndarray:
    """``(K, N)`` from per-target curves ``get(result) (L,)`` placed at their lives (NaN elsewhere)."""
    out = np.full((K, len(parts)), np.nan)
    for t, (k0, k1, r) in enumerate(parts):
        out[k0:k1, t] = get(r)
    return out


def case_bounds(x: torch.Tensor, alive: torch.Tensor, models: Models, P0: torch.Tensor) -> Bounds:
    """Per-trajectory PCRB of each target over its life (:class:`Bounds`)."""
    m = models
    full = _per_target(x, alive, lambda tr: pcrb(tr, m.motion, m.dt, m.q, m.model, m.R, P0))
    q0 = _per_target(x, alive, lambda tr: pcrb(tr, m.motion, m.dt, 0.0, m.model, m.R, P0))
    K = alive.shape[0]
    return Bounds(_curves(full, K, lambda b: b.position_rmse().numpy()), _curves(full, K, lambda b: b.velocity_rmse().numpy()),
                  _curves(full, K, lambda b: b.position_rmse("smoothing").numpy()),
                  _curves(full, K, lambda b: b.velocity_rmse("smoothing").numpy()),
                  _curves(q0, K, lambda b: b.position_rmse().numpy()),
                  _curves(q0, K, lambda b: b.position_rmse("smoothing").numpy()))


def memory_bounds(x: torch.Tensor, alive: torch.Tensor, methods, resources: dict, causal: dict[str, bool],
                  models: Models) -> dict[str, tuple[int, np.ndarray]]:
    """Per causal learned method, the filtering bound of only the scans its estimates read
    (:meth:`Tracker.memory` at the method's stride) with the training states' spread as prior: no
    network of that shape can beat it, whatever its training. Returns ``name -> (scans read,
    (K, N) curve)``; methods that share both share one computation."""
    out, cache = {}, {}
    m = models
    for spec in methods:
        if not method_kind(spec.kind).needs_checkpoint or not causal[spec.name]:
            continue
        t = resources[spec.name]
        stride = spec.option("stride")
        L, P0 = t.memory(None if stride is None else int(stride)), t.training_spread()
        key = (L, tuple(torch.diagonal(P0).tolist()))
        if key not in cache:
            parts = _per_target(x, alive, lambda tr: finite_memory_pcrb(tr, m.motion, m.dt, m.q, m.model, m.R, P0,
                                                                       memory=min(L, tr.shape[1])))
            cache[key] = min(L, alive.shape[0]), _curves(parts, alive.shape[0], lambda b: b.position_rmse().numpy())
        out[spec.name] = cache[key]
    return out


def _models(sc: Scenario, recipe: TrackRecipe) -> tuple[Models, MeasurementModel | None]:
    """The per-target stream models (the recipe's CA motion and q, the scenario's fixed noise) and,
    where the scenario makes detections, the detection model (pair layout)."""
    import dataclasses

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


def method_refusals(methods, kinds: dict, resources: dict, alive: torch.Tensor, case: str,
                    sensing: SensorSetup) -> list[str]:
    """What each method's kind refuses of one case (its ``check`` and ``check_sensing``), one
    message per refusal."""
    out = []
    for spec in methods:
        kind = kinds[spec.name]
        for check, args in ((kind.check, (spec, alive, resources.get(spec.name), case)),
                            (kind.check_sensing, (spec, sensing))):
            if check is None:
                continue
            try:
                check(*args)
            except ConfigError as exc:
                out.append(str(exc))
    return out


def case_maps(sc: Scenario, c, recipe: TrackRecipe, models: Models, sensing: SensorSetup, x: torch.Tensor,
              alive: torch.Tensor, targets: list[str]) -> tuple[SensorSetup, dict, list[str]]:
    """A case's range-Doppler maps (the scenario's ``rd_maps`` section with the case's overrides,
    :func:`~pmsr_nn.tbd.scene.build_scene`; frames are the case's scans): its sensing with them,
    what ``results.json`` records of them (``info["rd_maps"]``) and the refusals of maps that can
    not hold the case (one line each). A case without maps: its sensing as given, nothing else."""
    import dataclasses

    from ..tbd.scene import build_scene

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
            "present": present.tolist(), "table_frame": frame}
    return out, {"rd_maps": info}, []


def raise_refusals(refusals: list[str]) -> None:
    """Every refusal of a scenario file in one message (each said once, in order)."""
    if refusals:
        raise ConfigError("; ".join(dict.fromkeys(refusals)))


def prepare(sc, device: str = "cpu") -> Setup:
    """Resolve, design and check everything a scenario needs (every user error surfaces here,
    before any output is written): a :class:`~.scenario.Scenario` here, a multi-target study
    through :func:`.multitarget.prepare_multitarget`."""
    if not isinstance(sc, Scenario):
        from .multitarget import prepare_multitarget

        return prepare_multitarget(sc, device)
    recipe = load_recipe(sc.path(sc.recipe)) if sc.recipe else TrackRecipe()
    if recipe.dim != 2:
        raise ConfigError(f"scenario {sc.name!r}: the harness evaluates planar (dim 2) recipes")
    models, detection_model = _models(sc, recipe)
    prior_sd = recipe.initiation_prior_sd()
    kinds = {m.name: method_kind(m.kind) for m in sc.methods}
    context = _Context(sc, recipe, models.model, device)
    resources = {m.name: kinds[m.name].load(m, context) if kinds[m.name].load else None for m in sc.methods}
    causal = {m.name: bool(kinds[m.name].causal(resources[m.name])) for m in sc.methods}
    det = sc.detections
    sensing = SensorSetup(models.model, prior_sd, sc.noise.range_outlier_prob, sc.noise.range_outlier_scale,
                          detection_model, det.pd if det else None, det.clutter if det else None)
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
        if refusals:
            continue  # said once every case is checked; no bound is worth computing now
        # the PCRB is the recipe's measurement model's: a case only maps are formed of has none
        bounded = any(kinds[m.name].reads != "rd_maps" for m in sc.case_methods(c))
        bounds = case_bounds(x, alive, models, torch.diag(prior_sd**2)) if bounded else None
        mb = memory_bounds(x, alive, sc.methods, resources, causal, models)
        info = {"lives": [{"name": t.name, "first_scan": int(k0), "end_scan": int(k1)}
                            for t, (k0, k1) in zip(c.flights(), _lives(c, models.dt)[1])], **maps_info}
        # with maps, the set figures count every frame: a false track while no target lives is the seed's false alarm
        set_scans = torch.ones(alive.shape[0], dtype=torch.bool) if maps_info else None
        cases.append(Case(c.name, c.title or c.name, DesignedTruth(x, alive), case_sensing, alive, scored, targets, info,
                          bounds, mb, set_scans=set_scans, methods=tuple(c.methods)))
    raise_refusals(refusals)
    methods, tuning = sc.methods, {}
    if any(m.tuned() for m in sc.methods):  # last: the slowest check, after every quick one
        from .tuning import tune

        methods, tuning = tune(sc, recipe, models, prior_sd)
    settings = describe(sc, recipe, models, prior_sd, tuning, detection_model)
    definitions = DEFINITIONS
    if sc.rd_maps is not None:  # the track-before-detect rows' figures
        from .rd_maps_report import DEFINITIONS as TBD_DEFINITIONS

        definitions = {**DEFINITIONS, **TBD_DEFINITIONS}
    return Setup(sc, models, cases, methods, kinds, resources, causal, sc.random_streams,
                 (sc.set_metrics.c_m, sc.set_metrics.p), settings, definitions, recipe.geometry.build(2),
                 divergence_m=sc.divergence_m, tuning=tuning, recipe=recipe, prior_sd=prior_sd)


# ------------------------------------------------------------------ running blocks


def draw_block(setup: Setup, case_index: int, block: int) -> tuple[Truth, dict]:
    """The truth of one block's runs and every product its methods read (``name -> product``)."""
    sc, case = setup.scenario, setup.cases[case_index]
    b = len(sc.block_runs_range(block))
    g = seeded_generator(sc.seed, case_index, block)
    truth = case.truth.draw(b, g)
    products = {}
    for name in setup.products:
        kind = PRODUCTS[name]
        if setup.random_streams == "per_block":
            products[name] = kind.make(case.sensing, truth, g, g)
        else:
            products[name] = kind.make(case.sensing, truth, seeded_generator(sc.seed, case_index, block, kind.stream),
                                       seeded_generator(sc.seed, case_index, block, INIT_STREAM))
    return truth, products


def stream_block(setup: Setup, case_index: int, block: int):
    """Measurements ``z (b, K, m)`` and initiation prior (``x (b, n)``) of one block of a
    one-target case: what a single-target filter called directly reads (tests, benchmarks)."""
    from ..filters import Gaussian

    if setup.cases[case_index].multi_target:
        raise ValueError(f"case {setup.cases[case_index].name!r} has several targets; use draw_block")
    _, products = draw_block(setup, case_index, block)
    s = products["measurements"]
    return s.z[:, 0], Gaussian(s.prior.x[:, 0], s.prior.P[:, 0])


def call_method(setup: Setup, spec: MethodSpec, case: Case, products: dict, seed: tuple[int, ...]):
    """One method on one block through its registered kind: :class:`~pmsr_nn.trackers.base.Estimates`."""
    kind = setup.kinds[spec.name]
    call = MethodCall(spec, products[kind.reads], case.alive, setup.models, case.sensing, setup.resources[spec.name], seed)
    return kind.run(call)


def _first_runs(products: dict, b: int = 1) -> dict:
    """The products of the first ``b`` runs (a cheap call for the warm-up)."""
    from ..filters import Gaussian

    out = {}
    for name, p in products.items():
        if hasattr(p, "runs"):
            out[name] = p.runs(slice(0, b))
        else:
            out[name] = type(p)(p.z[:b], Gaussian(p.prior.x[:b], p.prior.P[:b]))
    return out


@dataclass
class BlockSums:
    """Raw per-block results of a shard: ``sums[case][method][q]`` stacks the blocks' sums of
    quantity ``q`` (:mod:`.scoring`; those in :data:`.scoring.PER_RUN` concatenate the runs),
    ``seconds[case][method]`` ``(blocks,)``, ``example[case][method]`` run 0's position
    estimates ``(K, N, 2)`` (only a shard holding block 0 has them; ``truth`` too)."""

    blocks: list[int]
    sums: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    example: dict = field(default_factory=dict)

    def add(self, case: str, method: str, values: dict[str, np.ndarray], seconds: float) -> None:
        per = self.sums.setdefault(case, {}).setdefault(method, {})
        for q, v in values.items():
            per.setdefault(q, []).append(np.asarray(v, dtype=np.float64))
        self.seconds.setdefault(case, {}).setdefault(method, []).append(seconds)

    def stacked(self) -> "BlockSums":
        """Lists of blocks joined into arrays (sums stacked, per-run quantities concatenated)."""
        out = BlockSums(self.blocks, example=self.example)
        for c, per in self.sums.items():
            for m, qs in per.items():
                out.sums.setdefault(c, {})[m] = {q: (np.concatenate(v) if q in scoring.PER_RUN else np.stack(v))
                                                 if isinstance(v, list) else v for q, v in qs.items()}
                s = self.seconds[c][m]
                out.seconds.setdefault(c, {})[m] = np.asarray(s, dtype=np.float64)
        return out

    def to_arrays(self) -> dict[str, np.ndarray]:
        bs = self.stacked()
        out = {"blocks": np.asarray(bs.blocks, dtype=np.int64)}
        for c, per in bs.sums.items():
            for m, qs in per.items():
                for q, a in qs.items():
                    out[f"sums/{c}/{m}/{q}"] = a
                out[f"seconds/{c}/{m}"] = bs.seconds[c][m]
        for c, per in bs.example.items():
            for m, a in per.items():
                out[f"example/{c}/{m}"] = a
        return out

    @classmethod
    def from_arrays(cls, arrays) -> "BlockSums":
        bs = cls([int(b) for b in arrays["blocks"]])
        for key in arrays:
            kind, *rest = key.split("/")
            if kind == "sums":
                c, m, q = rest
                bs.sums.setdefault(c, {}).setdefault(m, {})[q] = np.asarray(arrays[key])
            elif kind in ("seconds", "example"):
                c, m = rest
                getattr(bs, kind).setdefault(c, {})[m] = np.asarray(arrays[key])
        return bs

    @classmethod
    def concatenate(cls, parts: list["BlockSums"]) -> "BlockSums":
        """Shards (each :meth:`stacked`) in block order into one."""
        parts = sorted(parts, key=lambda p: p.blocks[0] if p.blocks else -1)
        out = cls([b for p in parts for b in p.blocks])
        for p in parts:
            for c, per in p.sums.items():
                for m, qs in per.items():
                    dst = out.sums.setdefault(c, {}).setdefault(m, {})
                    for q, a in qs.items():
                        dst[q] = a if q not in dst else np.concatenate([dst[q], a])
                    sec = out.seconds.setdefault(c, {})
                    sec[m] = p.seconds[c][m] if m not in sec else np.concatenate([sec[m], p.seconds[c][m]])
            for c, per in p.example.items():
                out.example.setdefault(c, {}).update(per)
        return out


def score(setup: Setup, case: Case, est, truth: Truth, space=None) -> dict[str, np.ndarray]:
    """Every sum :mod:`.scoring` keeps for one method's estimates of one block; ``space``: the
    :class:`~pmsr_nn.methods.EstimateSpace` the estimates live in (``truth`` then projected into it,
    :func:`truth_in`), whose columns ``pos`` / ``vel`` are scored as position and velocity."""
    pos, vel = list(setup.models.motion.pos_idx), list(setup.models.motion.vel_idx)
    if space is not None:
        pos, vel = list(space.pos), list(space.vel)
    if not (case.multi_target or not est.paired):
        out = scoring.point_sums(est, truth, case.scored, pos, vel)
    else:
        sets = scoring.per_scan_sets(est, truth, pos, *setup.set_metric)
        view = est if est.paired else scoring.matched_view(est, sets.assignment, truth.x.shape[2])
        out = scoring.point_sums(view, truth, case.scored, pos, vel)
        if est.paired:
            out.update(scoring.swaps(est, truth, pos))
        out.update(scoring.set_sums(est, truth, pos, *setup.set_metric, sc=sets))
        out.update(scoring.gospa_per_run(sets, case.set_scan_mask))
        out.update(scoring.track_sums(sets.assignment, est.exists, truth))
    if setup.loss is not None:
        out.update(scoring.loss_counts(est, setup.loss.successive_scans, setup.loss.gate_range_sd_m))
    if "max_duality_gap" in est.extras:
        out["gap"] = np.asarray(float(est.extras["max_duality_gap"]))
    out.update(scoring.extra_sums(est.extras))
    if est.extras.get("unlabelled"):
        out["unlabelled"] = np.asarray(1.0)
    if "tbd_detected" in est.extras:  # a track-before-detect method's per-frame figures
        out.update(scoring.tbd_sums(est, truth, pos, vel))
    return out


def method_space(setup: Setup, spec: MethodSpec, case: Case):
    """The :class:`~pmsr_nn.methods.EstimateSpace` a method's estimates live in (its kind's
    ``space``), or None: the scenario's state."""
    key = (case.name, spec.name)
    if key not in setup.spaces:
        kind = setup.kinds[spec.name]
        setup.spaces[key] = None if kind.space is None else kind.space(spec, case.sensing)
    return setup.spaces[key]


def truth_in(space, truth: Truth, projected: dict) -> Truth:
    """The block's ``truth`` in a method's ``space`` (itself for None): each living target's state
    through ``space.project`` (NaN where it does not live), once per block and space (``projected``
    keeps them by ``space.key``)."""
    if space is None:
        return truth
    if space.key not in projected:
        x = space.project(torch.nan_to_num(truth.x))
        nan = torch.full((), float("nan"), dtype=x.dtype)
        projected[space.key] = Truth(torch.where(truth.alive[..., None], x, nan), truth.alive)
    return projected[space.key]


def run_blocks(setup: Setup, blocks: range, progress: bool = True) -> BlockSums:
    """Run every method of every case on the given blocks of Monte Carlo runs."""
    from tqdm.auto import tqdm

    sc = setup.scenario
    out = BlockSums(list(blocks))
    called = [m for m in setup.methods if not setup.kinds[m.name].bound]  # a bound's row is filled by finalise
    bar = tqdm(total=len(blocks) * sum(case.runs(m) for case in setup.cases for m in called), disable=not progress,
               unit="method-block",
               desc=f"{sc.name}", leave=False)
    with torch.no_grad():
        for ci, case in enumerate(setup.cases):
            for block in blocks:
                truth, products = draw_block(setup, ci, block)
                for product in products.values():  # what a signal chain measured on the way
                    record = getattr(product, "front_end", None)
                    if record is not None:
                        out.add(case.name, FRONT_END, record.sums, 0.0)
                        if block == 0:
                            out.example.setdefault(case.name, {}).update(record.example)
                    if block == 0 and hasattr(product, "examples"):  # e.g. run 0's range-Doppler maps ("@" keys)
                        out.example.setdefault(case.name, {}).update(product.examples())
                todo = [m for m in called if case.runs(m) and m.name not in setup.warm]
                if todo:  # untimed, once per method (in its first case): start-up costs stay out of the timing
                    first = _first_runs(products)
                    for spec in todo:
                        call_method(setup, spec, case, first, (sc.seed, 1 << 30))
                        setup.warm.add(spec.name)
                pos = list(setup.models.motion.pos_idx)
                projected = {}  # the block's truth in each estimate space some method reads (truth_in)
                for spec in called:
                    if not case.runs(spec):
                        continue
                    interrupts.check()
                    bar.set_postfix_str(f"{case.name} {spec.name}", refresh=False)
                    t0 = time.perf_counter()
                    est = call_method(setup, spec, case, products, (sc.seed, ci, block))
                    # work reused from another method's call of this block (one PHD run for several
                    # labellings) counts in full in every method that reads it
                    seconds = time.perf_counter() - t0 + float(est.extras.get("shared_seconds", 0.0))
                    space = method_space(setup, spec, case)
                    out.add(case.name, spec.name, score(setup, case, est, truth_in(space, truth, projected), space), seconds)
                    if block == 0 and space is None:
                        x = torch.where(est.exists[0, ..., None], est.x[0][..., pos], float("nan"))
                        out.example.setdefault(case.name, {})[spec.name] = x.numpy()
                    elif block == 0:  # not a position: kept apart from the map's tracks ("@" keys)
                        x = torch.where(est.exists[0, ..., None], est.x[0], float("nan"))
                        out.example.setdefault(case.name, {})[f"@{spec.name}"] = x.numpy()
                    bar.update()
                if block == 0:
                    out.example.setdefault(case.name, {})["truth"] = truth.x[0][..., pos].numpy()
                    for key, t in projected.items():
                        out.example[case.name][f"@truth {key}"] = t.x[0].numpy()
    bar.close()
    return out.stacked()


# ------------------------------------------------------------------ the figures


def _mean(curve: np.ndarray, mask: np.ndarray) -> float:
    """Mean of ``curve (K, N)`` over the entries of ``mask`` (target by target for one target: the
    plain mean of its contiguous scans, as the papers average a curve)."""
    if not mask.any():  # e.g. a tracker that never matched a track: no scan to average
        return float("nan")
    if curve.shape[1] == 1:
        return float(curve[mask[:, 0], 0].mean())
    return float(curve[mask].mean())


def _root_se(per_run: np.ndarray | None, mean: float, p: float) -> float | None:
    """Standard error of ``mean ** (1/p)`` from the per-run values whose mean is ``mean`` (the
    delta method: ``se(mean) * mean ** (1/p - 1) / p``); None with fewer than two runs."""
    if per_run is None or len(per_run) < 2 or mean <= 0:
        return None
    se = float(np.std(per_run, ddof=1) / np.sqrt(len(per_run)))
    return se * mean ** (1.0 / p - 1.0) / p


def _set_figures(s: dict, R: int, scored: np.ndarray, p: float, scans: np.ndarray | None = None) -> tuple[dict, dict]:
    """Multi-target figures of one method: the row's fields and its per-scan curves; ``scans (K,)``:
    the scans the set figures average over (default: where some target is scored)."""
    k = scored.any(1) if scans is None else scans
    ospa_c = s["ospa"] / R
    assigned = np.sqrt(s["assigned_pos"] / np.where(s["assigned_count"] > 0, s["assigned_count"], np.nan))
    per_target = []
    for t in range(scored.shape[1]):
        v = assigned[scored[:, t], t]
        v = v[np.isfinite(v)]
        per_target.append(float(v.mean()) if len(v) else None)  # None: no run kept a track on it
    gp = (s["gospa_loc"] + s["gospa_missed"] + s["gospa_false"]) / R  # (K,) mean GOSPA^p per scan
    total = float(gp[k].mean())
    row = {"ospa_m": float(ospa_c[k].mean()), "gospa_m": total ** (1 / p),
           "gospa_se_m": _root_se(s.get("gospa_run"), total, p),
           "gospa_localisation_share": float((s["gospa_loc"][k] / R).mean() / total) if total > 0 else 0.0,
           "gospa_missed_share": float((s["gospa_missed"][k] / R).mean() / total) if total > 0 else 0.0,
           "gospa_false_share": float((s["gospa_false"][k] / R).mean() / total) if total > 0 else 0.0,
           "cardinality_mean_abs_error": float((s["abs_card"][k] / R).mean()),
           "rmse_pos_assigned_per_target_m": per_target,
           "label_switches_per_run": float(s["switches"].sum() / R),
           "label_switches_per_target": (s["switches"] / R).tolist()}
    if "swap" in s:  # paired slots only
        row["swap_probability"] = float(s["swap"].sum() / max(s["swap_n"].sum(), 1))
    if "tracks_per_target" in s:
        N = len(s["tracks_per_target"])
        first = s["first_track_scans"].sum() / s["first_track_count"].sum() if s["first_track_count"].sum() else None
        row.update({"confirmed_tracks_per_target": float(s["tracks_per_target"].sum() / (R * N)),
                    "false_tracks_per_run": float(s["false_tracks"] / R),
                    "missed_target_fraction": float(s["missed_scans"].sum() / max(s["alive_scans"].sum(), 1)),
                    "scans_to_first_track": None if first is None else float(first),
                    "track_loss_probability": float(s["lost_tracks"].sum() / (R * N)),
                    "fragmentations_per_run": float(s["fragmentations"].sum() / R),
                    "fragmentations_per_target": (s["fragmentations"] / R).tolist()})
    curves = {"ospa_m": ospa_c.tolist(), "gospa_m": (gp ** (1 / p)).tolist(), "cardinality": (s["n_est"] / R).tolist()}
    return row, curves


def _extra_figures(s: dict, R: int, n_blocks: int) -> tuple[dict, dict]:
    """Figures of the diagnostics some trackers report (:func:`.scoring.extra_sums`): the row's
    fields and per-scan curves (empty for a tracker without them)."""
    row, curves = {}, {}
    if "labels" in s:
        row["labels_per_run"] = float(s["labels"] / R)
    if "repaired" in s:
        row["conflicts_repaired_per_run"] = float(s["repaired"] / R)
    if "game_rounds" in s:
        row["game_rounds_mean"] = float(np.mean(s["game_rounds"] / n_blocks))
    if "phd_expected" in s:
        curves["phd_expected"] = (s["phd_expected"] / R).tolist()
    if "phd_particles" in s:
        row["phd_particles_mean"] = float(np.mean(s["phd_particles"] / R))
    if "phd_seconds" in s:
        row["phd_seconds_per_run"] = float(s["phd_seconds"] / R)
    return row, curves


def _unlabelled(N: int) -> dict:
    """A row of estimates without identity (extras ``unlabelled``: one set per scan, e.g. a PHD's own
    estimates): the figures that follow a track's label over scans do not apply (None); OSPA, GOSPA,
    cardinality, matched errors and fragmentations (gaps in a target's coverage) do."""
    return {"labelled": False, "label_switches_per_run": None, "label_switches_per_target": None,
            "rmse_pos_assigned_per_target_m": [None] * N, "confirmed_tracks_per_target": None,
            "false_tracks_per_run": None, "track_loss_probability": None}


def _space_fields(space, s: dict, scored: np.ndarray) -> dict:
    """What a row scored in an estimate space says of it: the space, what its "position" and
    "velocity" figures are, and the velocity RMSE pooled over the matched (run, scan, target)
    entries beside the pooled position one."""
    n = s["count"][scored].sum()
    return {"space": space.title, "space_key": space.key, "position": space.pos_label, "velocity": space.vel_label,
            "rmse_vel_pooled_mps": float(np.sqrt(s["vel"][scored].sum() / n)) if n else None}


def initiation(setup: Setup, spec: MethodSpec) -> str:
    """How a method's tracks start: ``association known`` (each target's own stream), ``oracle``
    (handed each target's birth: truth plus a prior draw) or ``detections`` (its own initiator)."""
    kind = setup.kinds[spec.name]
    if kind.initiation:
        return kind.initiation
    if kind.reads == "measurements":
        return "association known"
    if kind.starts_tracks:
        return "detections"
    return "detections" if "initiation" in kind.options and spec.option("initiation") == "detections" else "oracle"


def _under(mse: np.ndarray, curve: np.ndarray, scored: np.ndarray) -> tuple[float, float, bool]:
    """A method's error against a bound, with its Monte Carlo error: per run, the mean squared
    position error ``mse (R, N)`` over the bound's mean square on the scored scans (``curve (K,
    N)``, ``scored (K, N)``); returns that ratio's mean over the runs, its standard error and
    whether it is below 1 beyond its Monte Carlo error: the one-sided 97.5 % Student-t bound of
    the mean (``t`` with ``R - 1`` degrees of freedom times the standard error: 12.7 at 2 runs,
    2.78 at 5, 2.01 at 50) stays under 1. Only then is a method "below" the bound: with few runs
    a method can fall under it by chance, and two runs' standard error is itself a guess."""
    from scipy.stats import t as student_t

    ratio = mse.mean(1) / float(np.mean(curve[scored] ** 2))
    R = len(ratio)
    if R < 2:
        return float(ratio.mean()), float("inf"), False
    se = float(ratio.std(ddof=1) / np.sqrt(R))
    return float(ratio.mean()), se, bool(ratio.mean() + float(student_t.ppf(0.975, R - 1)) * se < 1)


def _pooled(s: dict, mask: np.ndarray, R: int, by_count: bool) -> float:
    """Root of the mean squared position error over the (run, target, scan) entries of ``mask``:
    weighted by the matched count of each scan (several targets, or tracks started from detections,
    which a run may lack at a scan), or over the runs (one target, one estimate per run and scan:
    the older studies' form, kept digit for digit); NaN where nothing was matched."""
    if by_count:
        n = s["count"][mask].sum()
        return float(np.sqrt(s["pos"][mask].sum() / n)) if n > 0 else float("nan")
    return float(np.sqrt((s["pos"][:, 0] / R)[mask[:, 0]].mean())) if mask.any() else float("nan")


def bound_row(spec: MethodSpec, case: Case, R: int) -> tuple[dict, list]:
    """The row of a ``kind: pcrb`` method (:mod:`pmsr_nn.methods.bound`) and its curve: the case's
    bound its options choose, averaged like ``rmse_pos_m``; no run time, no set figures (it
    estimates nothing)."""
    b = case.bounds
    smoothing, zero = spec.option("bound") == "smoothing", spec.option("q") == "zero"
    if zero:
        pos, vel = (b.q0_smoothing_pos if smoothing else b.q0_pos), None  # no velocity bound kept at q = 0
    else:
        pos, vel = (b.smoothing_pos, b.smoothing_vel) if smoothing else (b.pos, b.vel)
    scored, alive = case.scored.numpy(), case.alive.numpy()
    value = _mean(pos, scored)
    row = {"kind": spec.kind, "causal": not smoothing, "initiation": "association known",
           "bound": "smoothing" if smoothing else "filtering", "q": "zero" if zero else "model",
           "rmse_pos_m": value, "rmse_vel_mps": None if vel is None else _mean(vel, scored), "anees": None,
           "seconds_per_run": None, "rmse_pos_pooled_m": float(np.sqrt(np.mean(pos[scored] ** 2))),
           "rmse_pos_all_scans_m": _mean(pos, alive), "median_run_rmse_pos_m": None, "runs": R,
           "bound_pos_m": value, "over_bound": None, "below_bound": False}
    N = alive.shape[1]
    if N > 1:
        row["rmse_pos_per_target_m"] = [float(pos[scored[:, t], t].mean()) for t in range(N)]
        row["rmse_vel_per_target_mps"] = None if vel is None else [float(vel[scored[:, t], t].mean()) for t in range(N)]
        row["anees_per_target"] = None
    return row, pos[:, 0].tolist() if N == 1 else pos.T.tolist()


def finalise(setup: Setup, bs: BlockSums) -> dict:
    """The scenario's figures (the ``cases`` part of ``results.json``) from the sums of all blocks."""
    sc = setup.scenario
    if bs.blocks != list(range(sc.n_blocks)):
        raise ConfigError(f"the shards cover blocks {bs.blocks}, not all {sc.n_blocks}")
    R = sc.mc_runs
    cases = {}
    for case in setup.cases:
        scored = case.scored.numpy()
        alive = case.alive.numpy()
        N = alive.shape[1]
        b = case.bounds
        methods, curves, set_curves, run_rmse = {}, {}, {}, {}
        for spec in setup.methods:
            if not case.runs(spec):
                continue
            if setup.kinds[spec.name].bound:
                methods[spec.name], curves[spec.name] = bound_row(spec, case, R)
                continue
            s = {q: a.sum(0) if q not in scoring.PER_RUN else a for q, a in bs.sums[case.name][spec.name].items()}
            count = np.where(s["count"] > 0, s["count"], np.nan)
            rmse_p, rmse_v, nees = np.sqrt(s["pos"] / count), np.sqrt(s["vel"] / count), s["nees"] / count
            mse = s["run_mse"]  # (R, N)
            per_run = np.sqrt(mse.mean(1))  # per run: root of the mean over its targets' mean squared errors
            run_rmse[spec.name] = per_run
            starts = initiation(setup, spec)
            if starts == "detections":  # matched tracks: the scans some run had one (missed scans score elsewhere)
                m_scored, m_alive = scored & (s["count"] > 0), alive & (s["count"] > 0)
            else:
                m_scored, m_alive = scored, alive
            rmse = _mean(rmse_p, m_scored)
            row = {"kind": spec.kind, "causal": setup.causal[spec.name], "initiation": starts,
                   "rmse_pos_m": rmse, "rmse_vel_mps": _mean(rmse_v, m_scored),
                   "anees": None if np.isnan(s["nees"]).all() else _mean(nees, m_scored),
                   "seconds_per_run": float(bs.seconds[case.name][spec.name].sum() / R),
                   "rmse_pos_pooled_m": _pooled(s, m_scored, R, N > 1 or starts == "detections"),
                   "rmse_pos_all_scans_m": _mean(rmse_p, m_alive),
                   "median_run_rmse_pos_m": float(np.median(per_run)), "runs": R}
            if N > 1:
                row["rmse_pos_per_target_m"] = [float(rmse_p[m_scored[:, t], t].mean()) for t in range(N)]
                row["rmse_vel_per_target_mps"] = [float(rmse_v[m_scored[:, t], t].mean()) for t in range(N)]
                row["anees_per_target"] = None if row["anees"] is None else \
                    [float(nees[m_scored[:, t], t].mean()) for t in range(N)]
            if setup.divergence_m is not None:
                row["diverged_runs"] = int((~np.isfinite(per_run) | (per_run > setup.divergence_m)).sum())
            if "lost" in s:
                row["loss_probability"] = float(s["lost"].sum() / (R * N))
            if "gap" in s:
                row["max_duality_gap"] = float(bs.sums[case.name][spec.name]["gap"].max())
            if "ospa" in s:
                extra, set_curves[spec.name] = _set_figures(s, R, scored, setup.set_metric[1],
                                                            case.set_scan_mask.numpy())
                row.update(extra)
                extra, more = _extra_figures(s, R, sc.n_blocks)
                row.update(extra)
                set_curves[spec.name].update(more)
            if "unlabelled" in s:
                row.update(_unlabelled(N))
            space = method_space(setup, spec, case)
            if space is not None:
                row.update(_space_fields(space, s, m_scored))
            if b is not None:
                which = "filtering" if setup.causal[spec.name] else "smoothing"
                bound_p = _mean(b.pos if which == "filtering" else b.smoothing_pos, m_scored)
                floor = _mean(b.q0_pos if which == "filtering" else b.q0_smoothing_pos, m_scored)
                ratio, se, below = _under(mse, b.pos if which == "filtering" else b.smoothing_pos, m_scored)
                ratio0, se0, below0 = _under(mse, b.q0_pos if which == "filtering" else b.q0_smoothing_pos, m_scored)
                row.update({"bound": which, "bound_pos_m": bound_p, "over_bound": rmse / bound_p,
                            "mse_over_bound": ratio, "mse_over_bound_se": se, "below_bound": below,
                            "bound_q0_pos_m": floor, "mse_over_q0_bound": ratio0, "mse_over_q0_bound_se": se0,
                            "below_q0_bound": below0})
            res = setup.resources[spec.name]
            if setup.kinds[spec.name].needs_checkpoint:
                row.update({"checkpoint": res.source, "model": res.meta["model"]["kind"], "window": res.window})
                if spec.name in case.memory_bounds:
                    scans, curve = case.memory_bounds[spec.name]
                    mem = _mean(curve, m_scored)
                    ratio, se, below = _under(mse, curve, m_scored)
                    row.update({"memory_scans": scans, "memory_bound_pos_m": mem, "over_memory_bound": rmse / mem,
                                "mse_over_memory_bound": ratio, "mse_over_memory_bound_se": se,
                                "below_memory_bound": below})
            if "tbd_detected" in s:  # a track-before-detect method: the Remote Sensing 2020 figures per frame
                from .rd_maps_report import tbd_row

                row["tbd"] = tbd_row(s, R, case, spec)
            methods[spec.name] = row
            curves[spec.name] = rmse_p[:, 0].tolist() if N == 1 else rmse_p.T.tolist()
        out = {"title": case.title, "steps": case.steps, "targets": case.targets, **case.info, "methods": methods}
        if b is not None:
            out.update({"seed_groups": summarise_seeds(methods), "comparisons": comparisons(methods, run_rmse)})
            truth_xy = case.truth.x[..., list(setup.models.motion.pos_idx)]
            out["truth_pos_m"] = truth_xy[:, 0].tolist() if N == 1 else truth_xy.transpose(0, 1).tolist()
            out["pcrb"] = {"pos_m": _mean(b.pos, scored), "vel_mps": _mean(b.vel, scored),
                           "smoothing_pos_m": _mean(b.smoothing_pos, scored), "smoothing_vel_mps": _mean(b.smoothing_vel, scored),
                           "q0_pos_m": _mean(b.q0_pos, scored), "q0_smoothing_pos_m": _mean(b.q0_smoothing_pos, scored)}
            one = (lambda a: a[:, 0].tolist()) if N == 1 else (lambda a: a.T.tolist())
            out["curves"] = {"rmse_pos_m": curves, "pcrb_pos_m": one(b.pos), "pcrb_smoothing_pos_m": one(b.smoothing_pos),
                             "pcrb_q0_pos_m": one(b.q0_pos)}
        else:
            out["pcrb"] = None
            out["curves"] = {"rmse_pos_m": curves}
        if case.multi_target or set_curves:  # also one target seen by trackers that start their own tracks
            out["curves"].update({"set": set_curves, "cardinality_truth": alive.sum(1).tolist()})
        if FRONT_END in bs.sums.get(case.name, {}):
            from ..frontend.chain import summarise

            out["front_end"] = summarise({q: a.sum(0) for q, a in bs.sums[case.name][FRONT_END].items()},
                                         case.sensing.front_end)
        cases[case.name] = out
    return cases


DEFINITIONS = {
    "rmse_pos_m": "Eq. 31 of the MDFNN paper: at each step k the root of the mean over the Monte Carlo runs of the "
                  "squared Euclidean position error, then the mean of that curve over the steps after the warm-up "
                  "(with several targets: per target and step, then the mean over targets and their steps after "
                  "their own warm-up)",
    "rmse_pos_pooled_m": "root of the mean squared position error over runs, targets and steps after the warm-up (pooled)",
    "rmse_pos_all_scans_m": "the same as rmse_pos_m, averaged over every step each target lives (the S-MSJPDA paper)",
    "rmse_vel_per_target_mps": "per target: at each step the root of the mean over runs of the squared velocity error, "
                               "averaged over the target's steps after the warm-up (track slot i is target i's track)",
    "anees_per_target": "per target: the anees averaged over its steps after the warm-up",
    "anees": "mean over runs and steps after the warm-up of the NEES over the full state divided by its dimension "
             "(1 = consistent); null for methods without covariances",
    "pcrb": "per-trajectory posterior Cramer-Rao bound of each target's true trajectory under the recipe's CA model and "
            "q, the scenario's measurement deviations and the initiation prior P0, from the target's birth on clean "
            "(association-known) measurement streams; averaged like rmse_pos_m",
    "bound": "the bound a method is compared with: filtering for a causal method, smoothing for one that looks ahead",
    "memory_bound_pos_m": "finite-memory bound of a causal learned tracker: the filtering PCRB of only the memory_scans "
                          "scans its estimate at each step reads (an MDFNN's filter taps, a recurrent network's splice), "
                          "with the spread of its training states as prior; averaged like rmse_pos_m. No tracker of "
                          "that shape can beat it on average; below_memory_bound flags a mean per-run ratio of squared "
                          "error to the bound's mean square (mse_over_memory_bound) more than two standard errors under 1",
    "pcrb_q0": "the same bound with q = 0: the floor for an estimator that knew the target flies without process "
               "noise (the designed trajectories have none; exact CA for trajectories with constant acceleration)",
    "seed_groups": "learned methods named 'BASE [seed k]' (one training seed each) summarised per BASE: mean, "
                   "standard deviation over seeds, min and max of rmse_pos_m and of its ratios to the bounds",
    "comparisons": "each learned tracker (a seed group: the mean over its seeds per run) against the case's best "
                   "non-learned method on the same runs: margin_m = mean over runs of (classical - learned) per-run "
                   "position RMSE after the warm-up (positive: the learned tracker is better), se_m its standard error",
    "diverged_runs": "runs whose position RMSE after the warm-up exceeds divergence_m or is not finite; "
                     "they are kept in every average",
    "seconds_per_run": "wall-clock seconds of the method per Monte Carlo run, measured in this run (whole block "
                       "calls divided by the runs; all targets); timings differ between repeats",
    "ospa_m": "OSPA (Schuhmacher et al. 2008, cut-off c_m, order p) between the existing tracks and the living targets "
              "at each scan, averaged over runs, then over the scans after the warm-up",
    "gospa_m": "GOSPA (alpha = 2, Rahmathullah et al. 2017): the p-th root of the mean over runs and scans after the "
               "warm-up of GOSPA^p; gospa_localisation_share, gospa_missed_share and gospa_false_share split that "
               "mean into its parts (sum of d^p over assigned pairs, c^p/2 per missed target, c^p/2 per false track), "
               "which add up to 1; gospa_se_m its Monte Carlo standard error (the spread of the runs' mean GOSPA^p, "
               "through the p-th root by the delta method)",
    "confirmed_tracks_per_target": "reported tracks matched to a target (per-scan OSPA assignment) at some scan of "
                                   "its life, per target and run",
    "false_tracks_per_run": "reported tracks never matched to any target",
    "missed_target_fraction": "fraction of (run, target, scan) where the target lives and no track is matched to it",
    "scans_to_first_track": "scans from a target's birth to its first matched track, over the runs that had one",
    "track_loss_probability": "fraction of (run, target) whose matched tracks ended while the target still lived",
    "fragmentations_per_run": "interruptions of a target's matched coverage that resumed later, per run",
    "initiation": "how a row's tracks start: association known (each target's own stream), oracle (handed each "
                  "target's birth: truth plus a prior draw) or detections (the tracker's own initiator)",
    "cardinality_mean_abs_error": "mean over runs and scans after the warm-up of |number of tracks - number of targets|",
    "rmse_pos_assigned_per_target_m": "per target: each run's track labels are assigned to targets once (the assignment "
                                      "minimising the summed capped squared distances over the run), then the RMSE of "
                                      "the assigned track, averaged over the target's scans after the warm-up",
    "label_switches_per_run": "changes, between consecutive scans, of the track assigned to a target by the per-scan "
                              "OSPA assignment, summed over targets, per run",
    "swap_probability": "fraction of (run, target) tracks nearer another target's truth than their own at the last scan",
    "loss_probability": "fraction of (run, target) tracks declared lost by the S-MSJPDA paper's rule (dummy most "
                        "probable at every sensor for successive_scans scans in a row, or predicted bistatic-range "
                        "deviation above gate_range_sd_m); a lost track keeps being tracked and stays in the RMSE",
    "max_duality_gap": "largest duality gap (event cost minus Lagrangian lower bound, in nats: the event found is at "
                       "least exp(-gap) times as probable as the best) of the (N+1)-D assignments of P-MSJPDA",
}


def describe(sc: Scenario, recipe: TrackRecipe, models: Models, prior_sd: torch.Tensor, tuning: dict,
             detection_model: MeasurementModel | None) -> dict:
    """Settings recorded beside the figures."""
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
           "methods": {m.name: {"kind": m.kind, "reads": method_kind(m.kind).reads, **({"checkpoint": str(sc.path(m.checkpoint))} if m.checkpoint else {}),
                                **m.options, **({"tuning": tuning[m.name]} if m.name in tuning else {})}
                       for m in sc.methods}}
    if detection_model is not None:
        d = sc.detections
        lo, ext = d.clutter.box(d.components)
        out["detections"] = {"pd": d.pd, "components": list(d.components), "clutter_per_scan": d.clutter.per_scan,
                             "clutter_model": d.clutter.model, "clutter_box_si": [[a, a + e] for a, e in zip(lo, ext)],
                             "sensors": detection_model.n_pairs}
    if sc.random_streams != "per_block" or any(len(c.flights()) > 1 for c in sc.cases):
        out["random_streams"] = sc.random_streams
        out["set_metrics"] = {"c_m": sc.set_metrics.c_m, "p": sc.set_metrics.p}
    if sc.rd_maps is not None:  # the maps' section as given (each case's overrides are in its own results)
        from ..config import to_dict

        out["rd_maps"] = to_dict(sc.rd_maps)
        out["set_metrics"] = {"c_m": sc.set_metrics.c_m, "p": sc.set_metrics.p}
    return out
