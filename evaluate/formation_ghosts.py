"""Tracks held beside a target instead of on it: which runs of a multi-target scenario hold ghosts?

Re-draws the first ``--blocks`` blocks of a case (the same draws as ``pmsr evaluate``), runs the
chosen rows on them and prints, per row and run, the run's GOSPA (the p-th root of its mean
GOSPA^p over the scored scans, every living target counted, as in the report) and, per target, the median over its
scored life of the distance to the nearest reported track. A target whose nearest track stays
``--near`` m or more away (but within the GOSPA cut-off) for half its life while the tracker
reports about as many tracks as targets is held by a *ghost*: in a tight formation each pair's
detections can be explained by a permuted assignment (two members' bistatic ranges swapped at
some pairs), a consistent solution of the range equations that a 3-degree azimuth cannot rule
out, and a track started there stays there.

Each run's false-track cost (the c^p/2 GOSPA charges for reported tracks no living target is
assigned to) is split three ways, as shares of the run's GOSPA^p: a track that *outlived* its
target (assigned to a target at an earlier scan of its life, that target now dead), a track
*beside* a living target (within the cut-off of one, but another track holds it: a duplicate or
a ghost) and a track *far* from every living target (started on clutter, or drifted away).

    python evaluate/formation_ghosts.py evaluate/dense_crossing.yaml --methods S-MSJPDA --blocks 2
    python evaluate/formation_ghosts.py evaluate/one_sky.yaml --methods S-MSJPDA --only-blocks 0-24

Choosing a setting on draws no recorded study uses: ``--seed`` re-draws with another seed, and
``--options`` sets options of the chosen rows (a YAML mapping over the row's own). The scenario
``demo`` is the demo's one sky (:func:`pmsr_nn.harness.demo.demo_one_sky`, 2 runs a block):

    python evaluate/formation_ghosts.py evaluate/dense_crossing_bp.yaml --methods BP --seed 1000 --blocks 2 --options "{delete_existence: 1.0e-4}"
    python evaluate/formation_ghosts.py demo --methods BP --seed 1001
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
import yaml

from pmsr_nn.cli.evaluate import keep_methods, method_names
from pmsr_nn.errors import ConfigError
from pmsr_nn.harness.run.blocks import call_method, draw_block
from pmsr_nn.harness.scenario.loading import load_any
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.method_spec import MethodSpec
from pmsr_nn.metrics.sets import gospa, set_scores

FALSE_KINDS = ("outlived", "beside", "far")
"""How a false track's GOSPA charge is classed (:func:`false_kinds`)."""


def false_kinds(ex: torch.Tensor, exists: torch.Tensor, tx: torch.Tensor, alive: torch.Tensor, c: float,
                p: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(B, K, 3)``: per run and scan, the GOSPA^p charged for false tracks (c^p/2 each), split
    into :data:`FALSE_KINDS`; ``(B, K, T)`` the distance of each track charged as *beside* to
    the nearest living target (NaN elsewhere); and ``(B, K, T)`` which tracks are charged as false. ``ex (B, K, T, 2)`` track positions, ``exists (B,
    K, T)``, ``tx (B, K, N, 2)`` target positions, ``alive (B, K, N)``; a track slot that stops
    existing forgets its target (slots are reused)."""
    sc = set_scores(ex, exists, tx, alive, c, p)
    d = torch.cdist(ex, tx)  # (B, K, T, N)
    a = sc.assignment
    held = (a >= 0) & (d.gather(-1, a.clamp(min=0)[..., None])[..., 0] < c)  # within c: not charged as false
    false = exists & ~held
    nearest = torch.where(alive[:, :, None, :], d, torch.full((), float("inf"), dtype=d.dtype)).amin(-1)  # (B, K, T)
    near = nearest < c
    B, K, T = exists.shape
    last = torch.full((B, T), -1, dtype=torch.long)  # the target a slot's track was last held on
    out = torch.zeros(B, K, 3, dtype=ex.dtype)
    beside = torch.full_like(nearest, float("nan"))
    for k in range(K):
        last = torch.where(exists[:, k], last, torch.full_like(last, -1))
        dead = (last >= 0) & ~alive[:, k].gather(1, last.clamp(min=0))
        kind = torch.where(dead, 0, torch.where(near[:, k], 1, 2))  # outlived / beside / far
        out[:, k] = torch.nn.functional.one_hot(kind, 3).to(ex.dtype).mul(false[:, k, :, None]).sum(1) * c**p / 2
        beside[:, k] = torch.where(false[:, k] & (kind == 1), nearest[:, k], beside[:, k])
        last = torch.where(held[:, k], a[:, k], last)
    return out, beside, false


def longest_stretch(mask: torch.Tensor) -> torch.Tensor:
    """``(B,)``: the most consecutive scans any one slot of ``mask (B, K, T)`` is set (a false
    track's life: a slot holds one track until it is freed, and a freed slot is empty a scan)."""
    run = torch.zeros(mask.shape[0], mask.shape[2], dtype=torch.long)
    best = torch.zeros(mask.shape[0], dtype=torch.long)
    for k in range(mask.shape[1]):
        run = torch.where(mask[:, k], run + 1, 0)
        best = torch.maximum(best, run.amax(-1) if run.shape[1] else best)
    return best


def scenario_of(path: Path | str, seed: int | None = None, options: dict | None = None, methods: str | None = None):
    """The scenario to diagnose: the YAML at ``path`` (or ``demo``, the demo's one sky), re-drawn
    with ``seed`` (None: its own), with only the rows ``methods`` (comma-separated; None: all),
    each row's options updated by ``options`` (None: as given; checked as the row's own are)."""
    if str(path) == "demo":
        from pmsr_nn.harness.demo import ONE_SKY_RUNS, demo_one_sky

        sc = demo_one_sky(ONE_SKY_RUNS)
    else:
        sc = load_any(path, None, None)
    sc = sc.with_seed(seed)
    if methods:
        sc = keep_methods(sc, method_names(methods, [m.name for m in sc.methods]))
    if options:
        if not isinstance(options, dict):
            raise ConfigError(f"--options must be a YAML mapping of option: value, got {options!r}")
        sc = sc.replace(methods=tuple(MethodSpec(m.name, m.kind, m.checkpoint, {**m.options, **options})
                                      for m in sc.methods))
    return sc


def run_figures(path: Path, methods: list[str] | None, case: str | None, blocks: int | list[int],
                seed: int | None = None, options: dict | None = None) -> dict[str, dict]:
    """Per row: ``gospa_m (R,)`` each run's GOSPA, ``nearest_m (R, N)`` each target's median
    distance to the nearest reported track over its scored scans (inf: never a track) and
    ``false_shares (R, 3)`` the shares of each run's GOSPA^p charged for false tracks of each of
    :data:`FALSE_KINDS`, ``beside_m (R,)`` the median distance of the run's *beside* charges to
    the nearest living target (NaN: none), ``longest_false (R,)`` the most consecutive scored scans
    one track is charged as false (:func:`longest_stretch`). ``blocks``: the first so many blocks, or a list of block indices;
    ``seed``, ``options``: :func:`scenario_of`."""
    sc = scenario_of(path, seed, options, methods)
    names = [c.name for c in sc.cases]
    ci = names.index(case) if case in names else 0
    if case is not None and case not in names:
        raise ConfigError(f"no case {case!r} in {path} (cases: {', '.join(names)})")
    chosen = list(range(blocks)) if isinstance(blocks, int) else list(blocks)
    if not chosen or not all(0 <= b < sc.n_blocks for b in chosen):
        raise ConfigError(f"blocks must lie in 0..{sc.n_blocks - 1} (the first 1..{sc.n_blocks}), got {blocks}")
    setup = prepare(sc)
    c, p = sc.set_metrics.c_m, sc.set_metrics.p
    pos = list(setup.models.motion.pos_idx)
    cs = setup.cases[ci]
    scored, scans = cs.scored, cs.set_scan_mask
    out = {m.name: {"gospa_m": [], "nearest_m": [], "false_shares": [], "beside_m": [], "longest_false": []} for m in setup.methods}
    with torch.no_grad():
        for block in chosen:
            truth, products = draw_block(setup, ci, block)
            tx = truth.x[..., pos]  # (B, K, N, 2)
            for m in setup.methods:
                est = call_method(setup, m, cs, products, (sc.seed, ci, block))
                ex = est.x[..., pos]  # (B, K, T, 2)
                exists = est.exists & torch.isfinite(ex).all(-1)
                g = gospa(torch.nan_to_num(ex), exists, torch.nan_to_num(tx), truth.alive.expand(tx.shape[:3]), c, p)
                run_p = (g.total[:, scans] ** p).sum(1)  # (B,) the run's GOSPA^p over the scored scans
                out[m.name]["gospa_m"].append((run_p / int(scans.sum())) ** (1 / p))
                parts, beside, false = false_kinds(torch.nan_to_num(ex), exists, torch.nan_to_num(tx),
                                            truth.alive.expand(tx.shape[:3]), c, p)
                out[m.name]["false_shares"].append(parts[:, scans].sum(1) / run_p.clamp(min=1e-300)[:, None])
                out[m.name]["beside_m"].append(torch.nanmedian(beside[:, scans].flatten(1), 1).values)
                out[m.name]["longest_false"].append(longest_stretch(false[:, scans]))
                d = torch.cdist(torch.nan_to_num(tx, nan=1e12), torch.nan_to_num(ex, nan=-1e12))  # (B, K, N, T)
                d = torch.where(exists[:, :, None, :], d, torch.full((), float("inf"), dtype=d.dtype)).amin(-1)
                d = torch.where(scored, d, torch.full((), float("nan"), dtype=d.dtype))
                out[m.name]["nearest_m"].append(torch.nanmedian(d, 1).values)
    return {k: {q: torch.cat(v).numpy() for q, v in r.items()} for k, r in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--methods", help="rows to run (comma-separated names; default all)")
    ap.add_argument("--case", help="case name (default the first)")
    ap.add_argument("--blocks", type=int, default=1, help="first blocks of the case to draw (default 1)")
    ap.add_argument("--only-blocks", help="these blocks instead (e.g. 0-24 or 3,7,12: a block of one run is that run)")
    ap.add_argument("--seed", type=int, help="draw with this seed instead of the scenario's (e.g. 1000: no recorded "
                                             "study uses it)")
    ap.add_argument("--options", help="options of the chosen rows, a YAML mapping (e.g. \"{delete_existence: 1.0e-4}\")")
    ap.add_argument("--near", type=float, default=100.0, help="a nearest track this far or farther is beside its "
                                                               "target, not on it (m; default 100)")
    a = ap.parse_args()
    blocks = a.blocks
    if a.only_blocks:
        blocks = [i for part in a.only_blocks.split(",") for i in (
            range(int(part.split("-")[0]), int(part.split("-")[1]) + 1) if "-" in part else [int(part)])]
    try:
        options = yaml.safe_load(a.options) if a.options else None
    except yaml.YAMLError as exc:
        raise ConfigError(f"--options is not YAML: {exc}".splitlines()[0]) from None
    res = run_figures(a.scenario, a.methods, a.case, blocks, a.seed, options)
    sc = scenario_of(a.scenario, a.seed)
    run_ids = [i for b in (range(blocks) if isinstance(blocks, int) else blocks) for i in sc.block_runs_range(b)]
    for name, r in res.items():
        g, near = r["gospa_m"], r["nearest_m"]
        ghost = (near >= a.near) & np.isfinite(near)
        print(f"\n{name}: GOSPA over {len(g)} runs: mean {np.sqrt(np.mean(g ** 2)):.1f} m (root of the mean square), "
              f"median run {np.median(g):.1f} m; runs with a target held beside it ({a.near:g} m or more): "
              f"{int(ghost.any(1).sum())}; the longest-lived false track: {int(r['longest_false'].max())} scans")
        shares = r["false_shares"]
        weights = g ** 2 / np.sum(g ** 2)  # each run's share of the mean GOSPA^p (p = 2)
        print("share of the mean GOSPA^2 charged for false tracks: " + ", ".join(
            f"{kind} {100 * float(weights @ shares[:, i]):.0f} %" for i, kind in enumerate(FALSE_KINDS)))
        print(f"| run | GOSPA (m) | % of the run's GOSPA^2 false: {' / '.join(FALSE_KINDS)} | longest false track "
              "(scans) | beside: median distance to the nearest target (m) | per target: median distance to the "
              "nearest track (m) |")
        print("|---:|---:|---|---:|---:|---|")
        for i in range(len(g)):
            cells = " / ".join("-" if not np.isfinite(v) else f"{v:.0f}" + ("*" if ghost[i, t] else "")
                               for t, v in enumerate(near[i]))
            kinds = " / ".join(f"{100 * v:.0f}" for v in shares[i])
            far = r["beside_m"][i]
            print(f"| {run_ids[i]} | {g[i]:.1f} | {kinds} | {int(r['longest_false'][i])} | {'-' if np.isnan(far) else f'{far:.0f}'} | {cells} |")


if __name__ == "__main__":
    try:
        main()
    except ConfigError as exc:  # a bad scenario, row or option: one line, exit 2
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
