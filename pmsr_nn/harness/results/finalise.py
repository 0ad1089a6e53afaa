"""The figures of a scenario from its blocks' sums: the ``cases`` part of ``results.json``.

Takes a :class:`~pmsr_nn.harness.scenario.prepared.Setup` and the sums of all its blocks
(:class:`~pmsr_nn.harness.run.block_sums.BlockSums`, one run or merged shards, in block order);
gives per case its settings, one row per method (RMSE, ANEES, run time, the set and track figures
of multi-target rows, the figures of the metrics the row's kind declares,
:mod:`pmsr_nn.methods.kind_metrics`, the ratios to the case's bounds) and the curves the report
draws (:func:`finalise`), and the result kind (:func:`result_kind`).
Reducing the blocks in order is why merged shards give the unsharded figures bit for bit.

Shapes: ``B`` Monte Carlo runs, ``K`` scans, ``N`` targets; positions in m, velocities in m/s.
"""

from __future__ import annotations

import numpy as np

from ...errors import ConfigError
from ...frontend.chain import summarise
from ...methods.kind_metrics import RowContext
from ..run import scoring
from ..run.block_sums import FRONT_END, BlockSums
from ..scenario.method_spec import MethodSpec
from ..scenario.prepared import Case, Setup, method_space
from .paired import set_comparisons
from .result_rows import RUN_QUANTILES
from .seeds import comparisons, summarise_seeds

RESULT_KINDS = ("designed", "sampled")
"""``res["kind"]``: ``designed``, every case has its per-trajectory PCRB (designed flights every
run flies); ``sampled``, some case has none (truth sampled per run from a recipe, or a case only
maps are formed of)."""


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


def _se(per_run: np.ndarray | None) -> float | None:
    """Standard error of the mean of the finite per-run values; None with fewer than two."""
    if per_run is None:
        return None
    v = np.asarray(per_run, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.std(v, ddof=1) / np.sqrt(len(v))) if len(v) > 1 else None


def _rmse_se(mse: np.ndarray, rmse: float) -> float | None:
    """Standard error of a root-mean-square error ``rmse`` from the per-run mean squared errors
    ``mse (B, N)`` (each run's mean over its targets), by the delta method:
    ``se(rmse) = rmse * se(mean mse) / (2 mean mse)``; it treats the scans' average of per-scan RMSE
    like the root of the runs' mean MSE (they coincide when the error level is the same at every
    scan). None with fewer than two runs holding a finite value."""
    per_run = np.nanmean(np.where(np.isfinite(mse), mse, np.nan), axis=1) if mse.size else mse
    se = _se(per_run)
    mean = float(np.nanmean(per_run)) if se is not None else 0.0
    return None if se is None or mean <= 0 else rmse * se / (2.0 * mean)


def _median_root(per_run: np.ndarray | None, p: float) -> float | None:
    """The median over runs of each run's GOSPA (the p-th root of its mean GOSPA^p over the
    scored scans): a run that loses its tracks moves the mean, not this."""
    if per_run is None or not np.isfinite(per_run).any():
        return None
    return float(np.nanmedian(np.where(np.isfinite(per_run), per_run, np.nan) ** (1 / p)))


def _run_quantiles(per_run: np.ndarray | None, p: float) -> list[float] | None:
    """Each run's GOSPA (the p-th root of its mean GOSPA^p over the scored scans) at the
    :data:`RUN_QUANTILES` over the runs (linear interpolation between order statistics): where a
    few runs hold a false track for hundreds of scans, the mean says how much they cost and these
    say how many runs they are. None with fewer than two runs holding a finite value."""
    if per_run is None or np.isfinite(per_run).sum() < 2:
        return None
    roots = per_run[np.isfinite(per_run)] ** (1 / p)
    return [float(v) for v in np.quantile(roots, RUN_QUANTILES)]


def _set_figures(s: dict, B: int, scored: np.ndarray, p: float, scans: np.ndarray) -> tuple[dict, dict]:
    """Multi-target figures of one method: the row's fields and its per-scan curves; ``scans (K,)``:
    the scans the set figures average over (:func:`~pmsr_nn.harness.scenario.prepared.set_scans_after`)."""
    k = scans
    ospa_c = s["ospa"] / B
    assigned = np.sqrt(s["assigned_pos"] / np.where(s["assigned_count"] > 0, s["assigned_count"], np.nan))
    per_target = []
    for t in range(scored.shape[1]):
        v = assigned[scored[:, t], t]
        v = v[np.isfinite(v)]
        per_target.append(float(v.mean()) if len(v) else None)  # None: no run kept a track on it
    gp = (s["gospa_loc"] + s["gospa_missed"] + s["gospa_false"]) / B  # (K,) mean GOSPA^p per scan
    total = float(gp[k].mean())
    row = {"ospa_m": float(ospa_c[k].mean()), "gospa_m": total ** (1 / p),
           "gospa_se_m": _root_se(s.get("gospa_run"), total, p), "ospa_se_m": _se(s.get("ospa_run")),
           "gospa_median_run_m": _median_root(s.get("gospa_run"), p),
           "gospa_run_quantiles_m": _run_quantiles(s.get("gospa_run"), p),
           "gospa_localisation_share": float((s["gospa_loc"][k] / B).mean() / total) if total > 0 else 0.0,
           "gospa_missed_share": float((s["gospa_missed"][k] / B).mean() / total) if total > 0 else 0.0,
           "gospa_false_share": float((s["gospa_false"][k] / B).mean() / total) if total > 0 else 0.0,
           "cardinality_mean_abs_error": float((s["abs_card"][k] / B).mean()),
           "rmse_pos_assigned_per_target_m": per_target,
           "label_switches_per_run": float(s["switches"].sum() / B),
           "label_switches_per_target": (s["switches"] / B).tolist()}
    if "id_switches" in s:  # absent from blocks summed before it was kept
        row.update({"id_switches_per_run": float(s["id_switches"].sum() / B),
                    "id_switches_per_target": (s["id_switches"] / B).tolist()})
    if "swap" in s:  # paired slots only
        row["swap_probability"] = float(s["swap"].sum() / max(s["swap_n"].sum(), 1))
    if "tracks_per_target" in s:
        N = len(s["tracks_per_target"])
        first = s["first_track_scans"].sum() / s["first_track_count"].sum() if s["first_track_count"].sum() else None
        row.update({"confirmed_tracks_per_target": float(s["tracks_per_target"].sum() / (B * N)),
                    "false_tracks_per_run": float(s["false_tracks"] / B),
                    "missed_target_fraction": float(s["missed_scans"].sum() / max(s["alive_scans"].sum(), 1)),
                    "scans_to_first_track": None if first is None else float(first),
                    "track_loss_probability": float(s["lost_tracks"].sum() / (B * N)),
                    "fragmentations_per_run": float(s["fragmentations"].sum() / B),
                    "fragmentations_per_target": (s["fragmentations"] / B).tolist()})
        if "runs_without_tracks" in s:  # absent from blocks summed before it was kept
            row["runs_without_tracks"] = int(round(float(s["runs_without_tracks"])))
    curves = {"ospa_m": ospa_c.tolist(), "gospa_m": (gp ** (1 / p)).tolist(), "cardinality": (s["n_est"] / B).tolist()}
    return row, curves


def _trajectory_figures(s: dict, B: int, c: float, p: float) -> dict:
    """A row's trajectory GOSPA (:func:`pmsr_nn.harness.run.scoring.trajectory_sums`: switching cost ``gamma = c``,
    the LP relaxation) from its sums: the p-th root of the mean over runs of each run's value per
    set scan, its standard error, its parts' shares, switches per run and the runs whose LP
    solution was integral."""
    total = float(s["tgospa_run"].mean())
    share = lambda q: float(s[q] / B / total) if total > 0 else 0.0
    return {"tgospa_m": total ** (1 / p), "tgospa_se_m": _root_se(s["tgospa_run"], total, p), "tgospa_gamma_m": c,
            "tgospa_localisation_share": share("tgospa_loc"), "tgospa_missed_share": share("tgospa_missed"),
            "tgospa_false_share": share("tgospa_false"), "tgospa_switching_share": share("tgospa_switching"),
            "tgospa_switches_per_run": float(s["tgospa_switches"] / B),
            "tgospa_integral_runs": int(round(float(s["tgospa_integral"])))}


def complete(sums: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A method's block sums without the quantities some block lacks (blocks of a bank recorded
    before the quantity was kept, merged with newer ones): such a figure is left out, not summed
    over part of the runs. Per-run quantities have a row per run, the others one per block: a
    quantity with fewer than the most of its kind is incomplete."""
    most = {per: max((len(a) for q, a in sums.items() if scoring.per_run(q) == per), default=0)
            for per in (False, True)}
    return {q: a for q, a in sums.items() if len(a) == most[scoring.per_run(q)]}


def _space_fields(space, s: dict, scored: np.ndarray) -> dict:
    """What a row scored in an estimate space says of it: the space, what its "position" and
    "velocity" figures are, and the velocity RMSE pooled over the matched (run, scan, target)
    entries beside the pooled position one."""
    matched = s["count"][scored].sum()
    return {"space": space.title, "space_key": space.key, "position": space.pos_label, "velocity": space.vel_label,
            "rmse_vel_pooled_mps": float(np.sqrt(s["vel"][scored].sum() / matched)) if matched else None}


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
    position error ``mse (B, N)`` over the bound's mean square on the scored scans (``curve (K,
    N)``, ``scored (K, N)``); returns that ratio's mean over the runs, its standard error and
    whether it is below 1 beyond its Monte Carlo error: the one-sided 97.5 % Student-t bound of
    the mean (``t`` with ``B - 1`` degrees of freedom times the standard error: 12.7 at 2 runs,
    2.78 at 5, 2.01 at 50) stays under 1. Only then is a method "below" the bound: with few runs
    a method can fall under it by chance, and two runs' standard error is itself a guess."""
    from scipy.stats import t as student_t  # scipy.stats is slow to import: only when a bound is compared

    ratio = mse.mean(1) / float(np.mean(curve[scored] ** 2))
    B = len(ratio)
    if B < 2:
        return float(ratio.mean()), float("inf"), False
    se = float(ratio.std(ddof=1) / np.sqrt(B))
    return float(ratio.mean()), se, bool(ratio.mean() + float(student_t.ppf(0.975, B - 1)) * se < 1)


def _pooled(s: dict, mask: np.ndarray, B: int, by_count: bool) -> float:
    """Root of the mean squared position error over the (run, target, scan) entries of ``mask``:
    weighted by the matched count of each scan (several targets, or tracks started from detections,
    which a run may lack at a scan), or over the runs (one target, one estimate per run and scan:
    the older studies' form, kept digit for digit); NaN where nothing was matched."""
    if by_count:
        matched = s["count"][mask].sum()
        return float(np.sqrt(s["pos"][mask].sum() / matched)) if matched > 0 else float("nan")
    return float(np.sqrt((s["pos"][:, 0] / B)[mask[:, 0]].mean())) if mask.any() else float("nan")


def bound_row(spec: MethodSpec, case: Case, B: int) -> tuple[dict, list]:
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
           "rmse_pos_all_scans_m": _mean(pos, alive), "median_run_rmse_pos_m": None, "runs": B,
           "bound_pos_m": value, "over_bound": None, "below_bound": False}
    N = alive.shape[1]
    if N > 1:
        row["rmse_pos_per_target_m"] = [float(pos[scored[:, t], t].mean()) for t in range(N)]
        row["rmse_vel_per_target_mps"] = None if vel is None else [float(vel[scored[:, t], t].mean()) for t in range(N)]
        row["anees_per_target"] = None
    return row, pos[:, 0].tolist() if N == 1 else pos.T.tolist()


def _bound_fields(setup: Setup, spec: MethodSpec, case: Case, mse: np.ndarray, rmse: float,
                  m_scored: np.ndarray) -> dict:
    """A row's figures against its case's bounds: the PCRB (filtering for a causal method,
    smoothing for one that looks ahead, and its q = 0 floor) and, for a causal learned method, its
    finite-memory bound; ``mse (B, N)`` the per-run mean squared position errors, ``rmse`` the
    row's ``rmse_pos_m``, ``m_scored (K, N)`` its scored scans."""
    out = {}
    b = case.bounds
    if b is not None:
        which = "filtering" if setup.causal[spec.name] else "smoothing"
        bound_p = _mean(b.pos if which == "filtering" else b.smoothing_pos, m_scored)
        floor = _mean(b.q0_pos if which == "filtering" else b.q0_smoothing_pos, m_scored)
        ratio, se, below = _under(mse, b.pos if which == "filtering" else b.smoothing_pos, m_scored)
        ratio0, se0, below0 = _under(mse, b.q0_pos if which == "filtering" else b.q0_smoothing_pos, m_scored)
        out.update({"bound": which, "bound_pos_m": bound_p, "over_bound": rmse / bound_p,
                    "mse_over_bound": ratio, "mse_over_bound_se": se, "below_bound": below,
                    "bound_q0_pos_m": floor, "mse_over_q0_bound": ratio0, "mse_over_q0_bound_se": se0,
                    "below_q0_bound": below0})
    res = setup.resources[spec.name]
    if setup.kinds[spec.name].needs_checkpoint and setup.kinds[spec.name].reads != "measurements":
        out.update({"checkpoint": res.source, "model": res.meta["format"]})  # a learned tracker on detections
    elif setup.kinds[spec.name].needs_checkpoint:
        out.update({"checkpoint": res.source, "model": res.meta["model"]["kind"], "window": res.window})
        if spec.name in case.memory_bounds:
            scans, curve = case.memory_bounds[spec.name]
            mem = _mean(curve, m_scored)
            ratio, se, below = _under(mse, curve, m_scored)
            out.update({"memory_scans": scans, "memory_bound_pos_m": mem, "over_memory_bound": rmse / mem,
                        "mse_over_memory_bound": ratio, "mse_over_memory_bound_se": se,
                        "below_memory_bound": below})
    return out


def _own_figures(metrics: tuple, after: str, s: dict, ctx: RowContext, row: dict, curves: dict) -> None:
    """The fields and curves of the kind's ``metrics`` whose place in the row is ``after``
    (:data:`~pmsr_nn.methods.kind_metrics.AFTER`), into ``row`` and ``curves``."""
    for metric in metrics:
        if metric.after == after:
            extra, more = metric.compute(s, ctx)
            row.update(extra)
            curves.update(more)


def method_row(setup: Setup, bs: BlockSums, case: Case, spec: MethodSpec) -> tuple[dict, list, dict | None, np.ndarray]:
    """One method's row in one case from the sums of all blocks, its RMSE curve (``(K,)`` for one
    target, ``(N, K)`` otherwise, as lists), its set curves (None for a row without set figures)
    and its per-run position RMSE ``(B,)``."""
    sc = setup.scenario
    B = sc.mc_runs
    scored, alive = case.scored.numpy(), case.alive.numpy()
    N = alive.shape[1]
    blocks = complete(bs.sums[case.name][spec.name])
    s = {q: a if scoring.per_run(q) else a.sum(0) for q, a in blocks.items()}
    metrics = setup.kinds[spec.name].metrics  # the kind's own figures (pmsr_nn.methods.kind_metrics)
    ctx = RowContext(B, sc.n_blocks, N, case, spec, blocks)
    count = np.where(s["count"] > 0, s["count"], np.nan)
    rmse_p, rmse_v, nees = np.sqrt(s["pos"] / count), np.sqrt(s["vel"] / count), s["nees"] / count
    mse = s["run_mse"]  # (B, N)
    per_run = np.sqrt(mse.mean(1))  # per run: root of the mean over its targets' mean squared errors
    starts = initiation(setup, spec)
    if starts == "detections":  # matched tracks: the scans some run had one (missed scans score elsewhere)
        m_scored, m_alive = scored & (s["count"] > 0), alive & (s["count"] > 0)
    else:
        m_scored, m_alive = scored, alive
    rmse = _mean(rmse_p, m_scored)
    row = {"kind": spec.kind, "causal": setup.causal[spec.name], "initiation": starts,
           "rmse_pos_m": rmse, "rmse_pos_se_m": _rmse_se(mse, rmse), "rmse_vel_mps": _mean(rmse_v, m_scored),
           "anees": None if np.isnan(s["nees"]).all() else _mean(nees, m_scored),
           "seconds_per_run": float(bs.seconds[case.name][spec.name].sum() / B),
           "rmse_pos_pooled_m": _pooled(s, m_scored, B, N > 1 or starts == "detections"),
           "rmse_pos_all_scans_m": _mean(rmse_p, m_alive),
           "median_run_rmse_pos_m": float(np.median(per_run)), "runs": B}
    if N > 1:
        row["rmse_pos_per_target_m"] = [float(rmse_p[m_scored[:, t], t].mean()) for t in range(N)]
        row["rmse_vel_per_target_mps"] = [float(rmse_v[m_scored[:, t], t].mean()) for t in range(N)]
        row["anees_per_target"] = None if row["anees"] is None else \
            [float(nees[m_scored[:, t], t].mean()) for t in range(N)]
    if setup.divergence_m is not None:
        row["diverged_runs"] = int((~np.isfinite(per_run) | (per_run > setup.divergence_m)).sum())
    own_curves = {}  # per-scan curves of the kind's metrics: beside its set curves
    _own_figures(metrics, "point", s, ctx, row, own_curves)  # e.g. the loss rule
    set_curves = None
    if "ospa" in s:
        extra, set_curves = _set_figures(s, B, scored, setup.set_metric[1], case.set_scan_mask.numpy())
        row.update(extra)
        if "tgospa_run" in s:
            row.update(_trajectory_figures(s, B, *setup.set_metric))
    _own_figures(metrics, "sets", s, ctx, row, own_curves)  # e.g. a PHD's
    space = method_space(setup, spec, case)
    if space is not None:
        row.update(_space_fields(space, s, m_scored))
    row.update(_bound_fields(setup, spec, case, mse, rmse, m_scored))
    _own_figures(metrics, "bounds", s, ctx, row, own_curves)  # e.g. track-before-detect's per-frame part
    if own_curves:
        set_curves = {**(set_curves or {}), **own_curves}
    return row, rmse_p[:, 0].tolist() if N == 1 else rmse_p.T.tolist(), set_curves, per_run


def case_figures(setup: Setup, bs: BlockSums, case: Case) -> dict:
    """One case's entry of ``results.json``: its settings, every method's row, the PCRB where the
    case has one, and the curves."""
    B = setup.scenario.mc_runs
    scored, alive = case.scored.numpy(), case.alive.numpy()
    N = alive.shape[1]
    b = case.bounds
    methods, curves, set_curves, run_rmse, set_runs = {}, {}, {}, {}, {}
    for spec in setup.methods:
        if not case.runs(spec):
            continue
        if setup.kinds[spec.name].bound:
            methods[spec.name], curves[spec.name] = bound_row(spec, case, B)
            continue
        methods[spec.name], curves[spec.name], sets, run_rmse[spec.name] = method_row(setup, bs, case, spec)
        if sets is not None:
            set_curves[spec.name] = sets
            sums = bs.sums[case.name][spec.name]
            set_runs[spec.name] = {q: sums[q] for q in ("gospa_run", "ospa_run") if q in sums}
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
        out["set_comparisons"] = set_comparisons(methods, set_runs, setup.set_metric[1])
    if FRONT_END in bs.sums.get(case.name, {}):
        out["front_end"] = summarise({q: a.sum(0) for q, a in bs.sums[case.name][FRONT_END].items()},
                                     case.sensing.front_end)
    return out


def finalise(setup: Setup, bs: BlockSums) -> dict:
    """The scenario's figures (the ``cases`` part of ``results.json``) from the sums of all blocks."""
    sc = setup.scenario
    if bs.blocks != list(range(sc.n_blocks)):
        raise ConfigError(f"the shards cover blocks {bs.blocks}, not all {sc.n_blocks}")
    return {case.name: case_figures(setup, bs, case) for case in setup.cases}


def result_kind(setup: Setup) -> str:
    """``res["kind"]`` of a scenario's results (:data:`RESULT_KINDS`): ``designed`` where every
    case has its PCRB, else ``sampled``."""
    return "designed" if all(case.bounds is not None for case in setup.cases) else "sampled"
