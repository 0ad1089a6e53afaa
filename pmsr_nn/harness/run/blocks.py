"""Running a prepared scenario in blocks: every method of a case on the same Monte Carlo draws.

Takes a :class:`~pmsr_nn.harness.scenario.prepared.Setup` and the blocks of ``block_runs`` runs to
run (all, or a shard's slice, :func:`~.block_sums.shard_blocks`); gives the blocks' raw sums
(:class:`~.block_sums.BlockSums`). Per case and block the runner draws the truth, makes each sensor product the methods read
(:mod:`pmsr_nn.simulation.products`), calls every method on the whole block through its
registered kind (:mod:`pmsr_nn.methods`) and keeps the block's sums (:mod:`.scoring`, and those of
the metrics the kind declares, :mod:`pmsr_nn.methods.kind_metrics`).

Random streams: with ``per_block`` (the default, and the only choice of the older studies) one
generator seeded by ``(seed, case, block)`` gives the truth, then the product, then the initiation
prior. With ``per_product`` each product has its own generator ``(seed, case, block, stream)``
and the initiation prior one more, ``(seed, case, block, INIT_STREAM)``, shared by all products:
every method starts from the same tracks, and adding a method of another product changes no
other method's draws. A method that draws (the particle filter) has ``(seed, case, block,
crc32(name))``. A block's numbers therefore do not depend on which other blocks run beside it: a
shard ``I/N`` runs a contiguous slice of the blocks, and :func:`~pmsr_nn.harness.results.finalise.finalise` reduces the
blocks in order, which is why merged shards give the unsharded figures bit for bit.

Estimate spaces: a kind whose estimates are not the scenario's state declares the space they live
in (``MethodKind.space``, an :class:`~pmsr_nn.methods.EstimateSpace`: one pair's bistatic range
and range-rate, :mod:`pmsr_nn.methods.phd_pair`). :func:`score` then reads the block's truth
projected into that space (:func:`truth_in`, once per block and space) and scores the space's
"position" and "velocity" columns through the same set-metric path as every other row; the row
records its ``space`` and the report marks it, so a range-only OSPA is never read as a Cartesian one.
"""

from __future__ import annotations

import time

import numpy as np
import torch
from tqdm.auto import tqdm

from ... import interrupts
from ...filters import Gaussian
from ...methods import MethodCall
from ...methods.kind_metrics import BlockContext
from ...product_kinds import PRODUCTS
from ...rng import seeded_generator
from ...simulation.products import Truth
from ..scenario.method_spec import MethodSpec
from ..scenario.prepared import Case, Setup, method_space
from . import batches, scoring
from .block_sums import FRONT_END, BlockSums

INIT_STREAM = 0x696E6974
"""Last seed word of the initiation prior's generator under ``random_streams: per_product`` ('init')."""


def draw_block(setup: Setup, case_index: int, block: int) -> tuple[Truth, dict]:
    """The truth of one block's runs and every product its methods read (``name -> product``)."""
    sc, case = setup.scenario, setup.cases[case_index]
    B = len(sc.block_runs_range(block))
    g = seeded_generator(sc.seed, case_index, block)
    truth = case.truth.draw(B, g)
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
    """Measurements ``z (B, K, m)`` and initiation prior (``x (B, n)``) of one block of a
    one-target case: what a single-target filter called directly reads (tests, benchmarks)."""
    if setup.cases[case_index].multi_target:
        raise ValueError(f"case {setup.cases[case_index].name!r} has several targets; use draw_block")
    _, products = draw_block(setup, case_index, block)
    s = products["measurements"]
    return s.z[:, 0], Gaussian(s.prior.x[:, 0], s.prior.P[:, 0])


def call_method(setup: Setup, spec: MethodSpec, case: Case, products: dict, seed: tuple[int, ...],
                alive: torch.Tensor | None = None):
    """One method on one block through its registered kind: :class:`~pmsr_nn.trackers.base.Estimates`
    on the CPU. On another device (``setup.device``) the call's product, lives, models and sensing
    are moved there first (:meth:`~pmsr_nn.methods.MethodCall.to`; they were drawn on the CPU) and
    the estimates back after; on the CPU the call is made as it is. ``alive``: the targets' lives
    of ``products`` where they cover fewer scans than the case (the warm-up's slice)."""
    kind = setup.kinds[spec.name]
    alive = case.alive if alive is None else alive
    call = MethodCall(spec, products[kind.reads], alive, setup.models, case.sensing, setup.resources[spec.name], seed)
    device = torch.device(setup.device)
    if device.type == "cpu":
        return kind.run(call)
    return kind.run(call.to(device)).to("cpu")


WARM_SCANS = 30
"""Scans of the warm-up's slice after the case's first birth (:func:`warm_up`)."""


def warm_up(setup: Setup, spec: MethodSpec, case: Case, products: dict) -> None:
    """One untimed call of ``spec`` to pay its start-up costs (first calls of torch's kernels,
    lazy imports, a network's first pass) outside the timing: on the first run, over the scans up
    to ``WARM_SCANS`` after the case's first birth, so that a one-run study does not run twice. A
    kind the slice does not suit (a network whose window is longer than the slice) warms up on the
    whole first run instead; an error there is the kind's own and is raised."""
    first = _first_runs(products)
    alive = case.alive
    born = torch.nonzero(alive.any(1))
    W = min(alive.shape[0], (int(born[0]) if len(born) else 0) + WARM_SCANS)
    seed = (setup.scenario.seed, 1 << 30)
    if W < alive.shape[0]:
        try:
            call_method(setup, spec, case, {k: p.first_scans(W) for k, p in first.items()}, seed, alive[:W])
            return
        except Exception:  # noqa: BLE001 - the slice is only a shortcut; the whole run below decides
            pass
    call_method(setup, spec, case, first, seed)


def _first_runs(products: dict, B: int = 1) -> dict:
    """The products of the first ``B`` runs (a cheap call for the warm-up)."""
    out = {}
    for name, p in products.items():
        if hasattr(p, "runs"):
            out[name] = p.runs(slice(0, B))
        else:
            out[name] = type(p)(p.z[:B], Gaussian(p.prior.x[:B], p.prior.P[:B]))
    return out


def score(setup: Setup, case: Case, est, truth: Truth, space=None, metrics: tuple = ()) -> dict[str, np.ndarray]:
    """Every sum :mod:`.scoring` keeps for one method's estimates of one block, then those of the
    kind's own ``metrics`` (:class:`~pmsr_nn.methods.kind_metrics.Metric`, ``MethodKind.metrics``);
    ``space``: the :class:`~pmsr_nn.methods.EstimateSpace` the estimates live in (``truth`` then
    projected into it, :func:`truth_in`), whose columns ``pos`` / ``vel`` are scored as position and velocity."""
    pos, vel = list(setup.models.motion.pos_idx), list(setup.models.motion.vel_idx)
    if space is not None:
        pos, vel = list(space.pos), list(space.vel)
    sets = None
    if not (case.multi_target or not est.paired):
        out = scoring.point_sums(est, truth, case.scored, pos, vel)
    else:
        sets = scoring.per_scan_sets(est, truth, pos, *setup.set_metric)
        view = est if est.paired else scoring.matched_view(est, sets.assignment, truth.x.shape[2])
        out = scoring.point_sums(view, truth, case.scored, pos, vel)
        if est.paired:
            out.update(scoring.swaps(est, truth, pos))
        mapping = scoring.track_mapping(est, truth, pos, *setup.set_metric)
        out.update(scoring.set_sums(est, truth, pos, *setup.set_metric, sc=sets, mapping=mapping))
        out.update(scoring.gospa_per_run(sets, case.set_scan_mask))
        out.update(scoring.track_sums(mapping, est.exists, truth))
        if all(m.labelled(est) for m in metrics):  # a set without identities has no trajectories to score
            out.update(scoring.trajectory_sums(est, truth, pos, *setup.set_metric, case.set_scan_mask))
    ctx = BlockContext(pos, vel, setup.loss, None if sets is None or est.paired else sets.assignment,
                       setup.set_metric[0])
    for metric in metrics:
        out.update(metric.update(est, truth, ctx))
    return out


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


WARMED: set[tuple] = set()
"""The :func:`warm_key` of every method this process has called once, untimed, before its timed
calls (the warm-up of :func:`run_blocks`): a later evaluation in the same process (a merge's
evaluation, the next bank block, a notebook's second study, the tests) does not warm it again."""


def warm_key(spec: MethodSpec) -> tuple:
    """What a warm-up covers: the kind, its checkpoint and its options (another option may take
    another code path through the kind, with start-up costs of its own)."""
    return spec.kind, spec.checkpoint, repr(sorted(spec.options.items()))


def _method_calls(setup: Setup, spec: MethodSpec, case: Case, ci: int, group: list[int], drawn: dict):
    """``(block, estimates, seconds)`` of one method on every block of ``group``: one joined call
    where the kind is batchable and its product joins (:mod:`.batches`), else one call per block.
    A joined call's seconds are shared by the blocks in proportion to their runs."""
    sc = setup.scenario
    reads = setup.kinds[spec.name].reads
    parts = [drawn[b][1][reads] for b in group]
    if len(group) > 1 and setup.kinds[spec.name].batchable and batches.joinable(parts):
        runs = [len(sc.block_runs_range(b)) for b in group]
        t0 = time.perf_counter()
        est = call_method(setup, spec, case, {reads: batches.join(parts)}, (sc.seed, ci, group[0]))
        seconds = time.perf_counter() - t0
        for b, r, part in zip(group, runs, batches.split_estimates(est, runs)):
            yield b, part, seconds * r / sum(runs)
        return
    for b in group:
        t0 = time.perf_counter()
        est = call_method(setup, spec, case, drawn[b][1], (sc.seed, ci, b))
        # work reused from another method's call of this block (one PHD run for several
        # labellings) counts in full in every method that reads it
        yield b, est, time.perf_counter() - t0 + float(est.extras.get("shared_seconds", 0.0))


def run_blocks(setup: Setup, blocks, progress: bool = True, batch_runs: int = 1) -> BlockSums:
    """Run every method of every case on the given blocks of Monte Carlo runs (ascending block
    indices); ``batch_runs``: call a batchable kind on that many runs at once, in whole blocks
    (:mod:`.batches`; 1: block by block)."""
    sc = setup.scenario
    blocks = sorted(blocks)
    out = BlockSums(list(blocks))
    called = [m for m in setup.methods if not setup.kinds[m.name].bound]  # a bound's row is filled by finalise
    bar = tqdm(total=len(blocks) * sum(case.runs(m) for case in setup.cases for m in called), disable=not progress,
               unit="method-block",
               desc=f"{sc.name}", leave=False)
    groups = batches.batch_groups(blocks, batches.blocks_per_call(batch_runs, sc.block_runs))
    pos = list(setup.models.motion.pos_idx)
    with torch.no_grad():
        for ci, case in enumerate(setup.cases):
            for group in groups:
                drawn = {b: draw_block(setup, ci, b) for b in group}
                for block in group:
                    for product in drawn[block][1].values():  # what a signal chain measured on the way
                        record = getattr(product, "front_end", None)
                        if record is not None:
                            out.add(case.name, FRONT_END, record.sums, 0.0)
                            if block == 0:
                                out.example.setdefault(case.name, {}).update(record.example)
                        if block == 0 and hasattr(product, "examples"):  # e.g. run 0's range-Doppler maps ("@" keys)
                            out.example.setdefault(case.name, {}).update(product.examples())
                todo = [m for m in called if case.runs(m) and warm_key(m) not in WARMED]
                for spec in todo:  # untimed, once per process and kind (in its first case): start-up costs stay out of the timing
                    bar.set_postfix_str(f"{case.name} {spec.name} (warm-up, untimed)")  # not charged to a row
                    warm_up(setup, spec, case, drawn[group[0]][1])
                    WARMED.add(warm_key(spec))
                projected = {b: {} for b in group}  # each block's truth in the estimate spaces methods read (truth_in)
                for spec in called:
                    if not case.runs(spec):
                        continue
                    interrupts.check()
                    bar.set_postfix_str(f"{case.name} {spec.name}", refresh=False)
                    space = method_space(setup, spec, case)
                    for block, est, seconds in _method_calls(setup, spec, case, ci, group, drawn):
                        truth = truth_in(space, drawn[block][0], projected[block])
                        sums = score(setup, case, est, truth, space, setup.kinds[spec.name].metrics)
                        out.add(case.name, spec.name, sums, seconds)
                        if block == 0 and space is None:
                            x = torch.where(est.exists[0, ..., None], est.x[0][..., pos], float("nan"))
                            out.example.setdefault(case.name, {})[spec.name] = x.numpy()
                        elif block == 0:  # not a position: kept apart from the map's tracks ("@" keys)
                            x = torch.where(est.exists[0, ..., None], est.x[0], float("nan"))
                            out.example.setdefault(case.name, {})[f"@{spec.name}"] = x.numpy()
                        bar.update()
                if 0 in group:
                    out.example.setdefault(case.name, {})["truth"] = drawn[0][0].x[0][..., pos].numpy()
                    for key, t in projected[0].items():
                        out.example[case.name][f"@truth {key}"] = t.x[0].numpy()
    bar.close()
    return out.stacked()
