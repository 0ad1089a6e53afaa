"""Run a scenario: every method on the same Monte Carlo draws, in blocks, shardable.

Monte Carlo runs are processed in *blocks* of ``scenario.block_runs`` runs. Every random draw of
a block (measurement noise, the prior's offset, a particle filter's draws) comes from a
generator seeded by ``(seed, case, block)``, and every method runs on a whole block at once, so
a block's numbers do not depend on which other blocks run beside it. A shard ``I/N`` runs a
contiguous slice of the blocks; :func:`finalise` reduces the per-block sums in block order,
which is why shards merged give exactly (bit for bit) the unsharded figures.

Per block and method the raw sums kept are, per step ``k`` (``(K,)`` each):

* ``pos`` / ``vel``: sum over the block's runs of the squared position / velocity error (m^2, m^2/s^2);
* ``nees``: sum over runs of the NEES over the full state divided by its dimension (NaN for a
  method without covariances);

plus per run the mean squared position error after the warm-up (``run_mse``) and the block's
wall-clock seconds per method.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from .. import interrupts
from ..bounds import BoundResult, finite_memory_pcrb, pcrb
from ..errors import ConfigError
from ..filters import Gaussian
from ..measurements import wrap_angle
from ..metrics import normalised_nees, position_columns, squared_error, velocity_columns
from ..nets.inference import Tracker
from ..rng import seeded_generator, standard_normal
from ..simulation.recipe import TrackRecipe, load_recipe
from ..simulation.tracks import MEASUREMENT_COMPONENTS, apply_range_outliers, build_models, range_rows
from .methods import Models, is_causal, run_method
from .seeds import comparisons, summarise_seeds
from .scenario import FixedNoiseSpec, MethodSpec, Scenario
from .trajectories import check_inside, design_trajectory

QUANTITIES = ("pos", "vel", "nees")


@dataclass
class Case:
    """A case ready to run: truth ``(K, n)``, noise-free measurements ``(K, m)``, its bound under
    the recipe's q, the bound with q = 0 (no process noise: the designed flights have none) and,
    per causal learned method, its finite-memory bound (:func:`memory_bounds`)."""

    name: str
    title: str
    truth: torch.Tensor
    clean: torch.Tensor
    bound: BoundResult
    bound_q0: BoundResult
    memory_bounds: dict[str, tuple[int, BoundResult]] = field(default_factory=dict)


@dataclass
class Setup:
    """Everything a scenario run needs, resolved and checked before anything is written;
    ``methods`` are the scenario's with tuned options resolved, ``tuning`` the grid searches
    (method name -> record, :func:`~.tuning.tune`)."""

    scenario: Scenario
    recipe: TrackRecipe
    models: Models
    prior_sd: torch.Tensor
    cases: list[Case]
    trackers: dict[str, Tracker]
    causal: dict[str, bool]
    methods: tuple[MethodSpec, ...] = ()
    tuning: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        # the methods as run: the scenario's, with every 'tuned' option replaced by its choice
        if not self.methods:
            self.methods = self.scenario.methods


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


def prepare(sc: Scenario, device: str = "cpu") -> Setup:
    """Resolve the recipe, design and check the trajectories, load and check every checkpoint,
    compute each case's PCRB. Every user error surfaces here, before any output is written."""
    recipe = load_recipe(sc.path(sc.recipe)) if sc.recipe else TrackRecipe()
    if recipe.dim != 2:
        raise ConfigError(f"scenario {sc.name!r}: the harness evaluates planar (dim 2) recipes")
    motion, model = build_models(recipe)
    noise_std = torch.tensor(sc.noise.si(), dtype=torch.float64)
    R = model.R(noise_std)
    models = Models(motion, model, recipe.motion.dt_s, recipe.effective_motion().q_psd, R, noise_std)
    prior_sd = recipe.initiation_prior_sd()
    trackers = {}
    for spec in sc.methods:
        if spec.kind == "learned":
            path = sc.path(spec.checkpoint)
            t = Tracker.load(path, device=device)
            t.check_compatible(recipe.geometry.build(2).to_dict(), list(model.labels), recipe.motion.dt_s,
                               where=f"scenario {sc.name!r}")
            stride = spec.option("stride")
            if stride is not None and stride > t.window:
                raise ConfigError(f"method {spec.name!r}: stride {stride} is longer than the network's window of "
                                  f"{t.window} samples (scans between windows would get no estimate)")
            trackers[spec.name] = t
        if spec.kind == "imm":
            try:
                import pmsr_nn.filters.imm  # noqa: F401
            except ImportError:
                raise ConfigError(f"method {spec.name!r}: kind imm needs pmsr_nn.filters.imm, which this "
                                  "installation lacks") from None
    causal = {spec.name: is_causal(spec, trackers) for spec in sc.methods}
    cases = []
    for c in sc.cases:
        truth = design_trajectory(c, recipe, sc.ramp_s)
        check_inside(truth, recipe, c.name)
        K = len(truth)
        if sc.warmup_steps >= K:
            raise ConfigError(f"case {c.name!r} has {K} steps; warmup_steps {sc.warmup_steps} leaves none to average")
        for name, t in trackers.items():
            if t.window > K:
                raise ConfigError(f"case {c.name!r} has {K} steps, fewer than {name}'s window of {t.window}")
        P0 = torch.diag(prior_sd**2)
        bound = pcrb(truth[None], motion, models.dt, models.q, model, R, P0)
        bound_q0 = pcrb(truth[None], motion, models.dt, 0.0, model, R, P0)
        cases.append(Case(c.name, c.title or c.name, truth, model.h(truth), bound, bound_q0,
                          memory_bounds(truth, sc.methods, trackers, causal, models)))
    methods, tuning = sc.methods, {}
    if any(m.tuned() for m in sc.methods):  # last: the slowest check, after every quick one
        from .tuning import tune

        methods, tuning = tune(sc, recipe, models, prior_sd)
    return Setup(sc, recipe, models, prior_sd, cases, trackers, causal, methods, tuning)


def memory_bounds(truth: torch.Tensor, methods, trackers: dict[str, Tracker], causal: dict[str, bool],
                  models: Models) -> dict[str, tuple[int, BoundResult]]:
    """Per causal learned method, the filtering bound of only the scans its estimates read
    (:meth:`Tracker.memory` at the method's stride) with the training states' spread as prior:
    no network of that shape can beat it, whatever its training. ``truth (K, n)``; returns
    ``name -> (scans read, bound)``; methods that share both share one computation."""
    out, cache = {}, {}
    for spec in methods:
        if spec.kind != "learned" or not causal[spec.name]:
            continue
        t = trackers[spec.name]
        stride = spec.option("stride")
        L, P0 = min(t.memory(None if stride is None else int(stride)), len(truth)), t.training_spread()
        key = (L, tuple(torch.diagonal(P0).tolist()))
        if key not in cache:
            cache[key] = L, finite_memory_pcrb(truth[None], models.motion, models.dt, models.q, models.model,
                                               models.R, P0, memory=L)
        out[spec.name] = cache[key]
    return out


def draw_runs(clean: torch.Tensor, start: torch.Tensor, b: int, models: Models, prior_sd: torch.Tensor,
              noise: FixedNoiseSpec, g: torch.Generator) -> tuple[torch.Tensor, Gaussian]:
    """Measurements ``(b, K, m)`` of ``b`` runs around noise-free ``clean`` (``(K, m)``, shared, or
    ``(b, K, m)``) and their initiation priors around true initial states ``start`` (``(n,)`` or
    ``(b, n)``), in this order from ``g``: measurement noise, prior offsets, then (only with
    outliers) one uniform per range measurement."""
    noise_draw = standard_normal((b, *clean.shape[-2:]), g)
    z = clean + noise_draw * models.model.std_vector(models.noise_std)
    angles = models.model.angle_mask
    z = torch.where(angles, wrap_angle(z), z)
    n = start.shape[-1]
    x0 = start + standard_normal((b, n), g) * prior_sd
    P0 = torch.diag(prior_sd**2).expand(b, n, n).clone()
    z = apply_range_outliers(z, clean, range_rows(models.model), noise.range_outlier_prob, noise.range_outlier_scale, g)
    return z, Gaussian(x0, P0)


def draw_block(setup: Setup, case_index: int, block: int) -> tuple[torch.Tensor, Gaussian]:
    """Measurements ``(b, K, m)`` and the initiation prior of the runs of one block."""
    sc, case = setup.scenario, setup.cases[case_index]
    b = len(sc.block_runs_range(block))
    g = seeded_generator(sc.seed, case_index, block)
    return draw_runs(case.clean, case.truth[0], b, setup.models, setup.prior_sd, sc.noise, g)


@dataclass
class BlockSums:
    """Raw per-block results of a shard: ``sums[case][method][q]`` is ``(blocks, K)`` for ``q`` in
    :data:`QUANTITIES`, ``run_mse[case][method]`` ``(runs,)``, ``seconds[case][method]`` ``(blocks,)``,
    ``example[case][method]`` the position estimates ``(K, 2)`` of run 0 (shard holding block 0 only)."""

    blocks: list[int]
    sums: dict = field(default_factory=dict)
    run_mse: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    example: dict = field(default_factory=dict)

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"blocks": np.asarray(self.blocks, dtype=np.int64)}
        for c, per in self.sums.items():
            for m, qs in per.items():
                for q, a in qs.items():
                    out[f"sums/{c}/{m}/{q}"] = a
                out[f"run_mse/{c}/{m}"] = self.run_mse[c][m]
                out[f"seconds/{c}/{m}"] = self.seconds[c][m]
        for c, per in self.example.items():
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
            elif kind in ("run_mse", "seconds", "example"):
                c, m = rest
                getattr(bs, kind).setdefault(c, {})[m] = np.asarray(arrays[key])
        return bs


def warm_up(setup: Setup, z: torch.Tensor, prior: Gaussian) -> None:
    """One untimed call of every method on one run, so that one-off start-up costs (library
    loading, allocator growth) do not land in the first block's timing."""
    one = Gaussian(prior.x[:1], prior.P[:1])
    for spec in setup.methods:
        run_method(spec, z[:1], one, setup.models, setup.trackers, (setup.scenario.seed, 1 << 30))


def run_blocks(setup: Setup, blocks: range, progress: bool = True) -> BlockSums:
    """Run every method of every case on the given blocks of Monte Carlo runs."""
    from tqdm.auto import tqdm

    sc = setup.scenario
    out = BlockSums(list(blocks))
    bar = tqdm(total=len(setup.cases) * len(blocks) * len(setup.methods), disable=not progress, unit="method-block",
               desc=f"{sc.name}", leave=False)
    with torch.no_grad():
        for ci, case in enumerate(setup.cases):
            n = case.truth.shape[-1]
            pos, vel = position_columns(n), velocity_columns(n)
            sums = {m.name: {q: [] for q in QUANTITIES} for m in setup.methods}
            run_mse = {m.name: [] for m in setup.methods}
            seconds = {m.name: [] for m in setup.methods}
            for block in blocks:
                z, prior = draw_block(setup, ci, block)
                truth = case.truth.expand(len(z), -1, -1)
                if ci == 0 and block == blocks[0]:
                    warm_up(setup, z, prior)
                for spec in setup.methods:
                    interrupts.check()
                    bar.set_postfix_str(f"{case.name} {spec.name}", refresh=False)
                    t0 = time.perf_counter()
                    res = run_method(spec, z, prior, setup.models, setup.trackers, (sc.seed, ci, block))
                    seconds[spec.name].append(time.perf_counter() - t0)
                    se_p, se_v = squared_error(res.x, truth, pos), squared_error(res.x, truth, vel)
                    nees = normalised_nees(res.x, res.P, truth) if res.P is not None else torch.full_like(se_p, float("nan"))
                    for q, v in zip(QUANTITIES, (se_p, se_v, nees)):
                        sums[spec.name][q].append(v.sum(0).numpy())
                    run_mse[spec.name].append(se_p[:, sc.warmup_steps:].mean(1).numpy())
                    if block == 0:
                        out.example.setdefault(case.name, {})[spec.name] = res.x[0][:, pos].numpy()
                    bar.update()
            out.sums[case.name] = {m: {q: np.stack(v) for q, v in qs.items()} for m, qs in sums.items()}
            out.run_mse[case.name] = {m: np.concatenate(v) for m, v in run_mse.items()}
            out.seconds[case.name] = {m: np.asarray(v) for m, v in seconds.items()}
    bar.close()
    return out


def finalise(setup: Setup, bs: BlockSums) -> dict:
    """The scenario's figures (the ``cases`` part of ``results.json``) from the sums of all blocks."""
    sc = setup.scenario
    if bs.blocks != list(range(sc.n_blocks)):
        raise ConfigError(f"the shards cover blocks {bs.blocks}, not all {sc.n_blocks}")
    R, w = sc.mc_runs, sc.warmup_steps
    cases = {}
    for case in setup.cases:
        b, b0 = case.bound, case.bound_q0
        bounds = {"filtering": (b.position_rmse().numpy(), b.velocity_rmse().numpy()),
                  "smoothing": (b.position_rmse("smoothing").numpy(), b.velocity_rmse("smoothing").numpy())}
        floor = {"filtering": b0.position_rmse().numpy(), "smoothing": b0.position_rmse("smoothing").numpy()}
        methods, curves = {}, {}
        for spec in sc.methods:
            s = {q: bs.sums[case.name][spec.name][q].sum(0) / R for q in QUANTITIES}
            rmse_p, rmse_v = np.sqrt(s["pos"]), np.sqrt(s["vel"])
            run_rmse = np.sqrt(bs.run_mse[case.name][spec.name])
            which = "filtering" if setup.causal[spec.name] else "smoothing"
            bound_p = float(bounds[which][0][w:].mean())
            rmse = float(rmse_p[w:].mean())
            row = {"rmse_pos_m": rmse, "rmse_vel_mps": float(rmse_v[w:].mean()),
                   "anees": None if np.isnan(s["nees"]).all() else float(s["nees"][w:].mean()),
                   "seconds_per_run": float(bs.seconds[case.name][spec.name].sum() / R),
                   "rmse_pos_pooled_m": float(np.sqrt(s["pos"][w:].mean())),
                   "kind": spec.kind, "causal": setup.causal[spec.name], "bound": which, "bound_pos_m": bound_p,
                   "over_bound": rmse / bound_p, "below_bound": bool(rmse < bound_p),
                   "bound_q0_pos_m": float(floor[which][w:].mean()),
                   "below_q0_bound": bool(rmse < float(floor[which][w:].mean())),
                   "diverged_runs": int((~np.isfinite(run_rmse) | (run_rmse > sc.divergence_m)).sum()),
                   "median_run_rmse_pos_m": float(np.median(run_rmse)), "runs": R}
            if spec.kind == "learned":
                t = setup.trackers[spec.name]
                row.update({"checkpoint": t.source, "model": t.meta["model"]["kind"], "window": t.window})
                if spec.name in case.memory_bounds:
                    scans, mb = case.memory_bounds[spec.name]
                    curve = mb.position_rmse().numpy()[w:]
                    mem = float(curve.mean())
                    # per run: mean squared error over the bound's mean square; "below" only when the
                    # mean ratio is more than two Monte Carlo standard errors under 1
                    ratio = bs.run_mse[case.name][spec.name] / float((curve**2).mean())
                    se = float(ratio.std(ddof=1) / np.sqrt(len(ratio))) if len(ratio) > 1 else float("inf")
                    row.update({"memory_scans": scans, "memory_bound_pos_m": mem, "over_memory_bound": rmse / mem,
                                "mse_over_memory_bound": float(ratio.mean()), "mse_over_memory_bound_se": se,
                                "below_memory_bound": bool(ratio.mean() + 2 * se < 1)})
            methods[spec.name] = row
            curves[spec.name] = rmse_p.tolist()
        cases[case.name] = {
            "title": case.title, "steps": len(case.truth),
            "methods": methods,
            "seed_groups": summarise_seeds(methods),
            "comparisons": comparisons(methods, {n: np.sqrt(bs.run_mse[case.name][n]) for n in methods}),
            "truth_pos_m": case.truth[:, position_columns(case.truth.shape[-1])].tolist(),
            "pcrb": {"pos_m": float(bounds["filtering"][0][w:].mean()), "vel_mps": float(bounds["filtering"][1][w:].mean()),
                     "smoothing_pos_m": float(bounds["smoothing"][0][w:].mean()),
                     "smoothing_vel_mps": float(bounds["smoothing"][1][w:].mean()),
                     "q0_pos_m": float(floor["filtering"][w:].mean()),
                     "q0_smoothing_pos_m": float(floor["smoothing"][w:].mean())},
            "curves": {"rmse_pos_m": curves, "pcrb_pos_m": bounds["filtering"][0].tolist(),
                       "pcrb_smoothing_pos_m": bounds["smoothing"][0].tolist(),
                       "pcrb_q0_pos_m": floor["filtering"].tolist()},
        }
    return cases


DEFINITIONS = {
    "rmse_pos_m": "Eq. 31 of the MDFNN paper: at each step k the root of the mean over the Monte Carlo runs of the "
                  "squared Euclidean position error, then the mean of that curve over steps warmup_steps..K-1",
    "rmse_pos_pooled_m": "root of the mean squared position error over runs and steps warmup_steps..K-1 (pooled)",
    "anees": "mean over runs and steps after the warm-up of the NEES over the full state divided by its dimension "
             "(1 = consistent); null for methods without covariances",
    "pcrb": "per-trajectory posterior Cramer-Rao bound of the case's true trajectory under the recipe's CA model and "
            "q, the scenario's measurement deviations and the initiation prior P0; averaged like rmse_pos_m",
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
                       "calls divided by the runs); timings differ between repeats",
}


def describe(setup: Setup) -> dict:
    """Settings recorded beside the figures."""
    sc, r = setup.scenario, setup.recipe
    return {"recipe": str(sc.path(sc.recipe)) if sc.recipe else "built-in FITEE 2023 CA recipe", "variant": r.variant, "dt_s": r.motion.dt_s, "q_psd": setup.models.q,
            "noise": {"range_m": sc.noise.range_m, "range_rate_mps": sc.noise.range_rate_mps,
                      "azimuth_deg": sc.noise.azimuth_deg,
                      **({"range_outlier_prob": sc.noise.range_outlier_prob,
                          "range_outlier_scale": sc.noise.range_outlier_scale} if sc.noise.has_outliers else {})},
            "measurement_components": list(MEASUREMENT_COMPONENTS), "prior_sd": setup.prior_sd.tolist(),
            "prior": "per run: mean = truth at step 0 + a draw from N(0, P0), P0 = diag(prior_sd^2); the PCRB uses P0",
            "warmup_steps": sc.warmup_steps, "divergence_m": sc.divergence_m, "block_runs": sc.block_runs,
            "methods": {m.name: {"kind": m.kind, **({"checkpoint": str(sc.path(m.checkpoint))} if m.checkpoint else {}),
                                 **m.options, **({"tuning": setup.tuning[m.name]} if m.name in setup.tuning else {})}
                        for m in sc.methods}}
