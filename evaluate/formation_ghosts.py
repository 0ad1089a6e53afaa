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

    python evaluate/formation_ghosts.py evaluate/dense_crossing.yaml --methods S-MSJPDA --blocks 2
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from pmsr_nn.cli.evaluate import keep_methods, method_names
from pmsr_nn.errors import ConfigError
from pmsr_nn.harness.blocks import call_method, draw_block
from pmsr_nn.harness.evaluate import load_any
from pmsr_nn.harness.runner import prepare
from pmsr_nn.metrics.sets import gospa


def run_figures(path: Path, methods: list[str] | None, case: str | None, blocks: int) -> dict[str, dict]:
    """Per row: ``gospa_m (R,)`` each run's GOSPA and ``nearest_m (R, N)`` each target's median
    distance to the nearest reported track over its scored scans (inf: never a track)."""
    sc = load_any(path, None, None)
    if methods:
        sc = keep_methods(sc, method_names(methods, [m.name for m in sc.methods]))
    names = [c.name for c in sc.cases]
    ci = names.index(case) if case in names else 0
    if case is not None and case not in names:
        raise ConfigError(f"no case {case!r} in {path} (cases: {', '.join(names)})")
    if not 1 <= blocks <= sc.n_blocks:
        raise ConfigError(f"--blocks must be 1..{sc.n_blocks}, got {blocks}")
    setup = prepare(sc)
    c, p = sc.set_metrics.c_m, sc.set_metrics.p
    pos = list(setup.models.motion.pos_idx)
    cs = setup.cases[ci]
    scored, scans = cs.scored, cs.set_scan_mask
    out = {m.name: {"gospa_m": [], "nearest_m": []} for m in setup.methods}
    with torch.no_grad():
        for block in range(blocks):
            truth, products = draw_block(setup, ci, block)
            tx = truth.x[..., pos]  # (B, K, N, 2)
            for m in setup.methods:
                est = call_method(setup, m, cs, products, (sc.seed, ci, block))
                ex = est.x[..., pos]  # (B, K, T, 2)
                exists = est.exists & torch.isfinite(ex).all(-1)
                g = gospa(torch.nan_to_num(ex), exists, torch.nan_to_num(tx), truth.alive.expand(tx.shape[:3]), c, p)
                out[m.name]["gospa_m"].append((g.total[:, scans] ** p).mean(1) ** (1 / p))
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
    ap.add_argument("--near", type=float, default=100.0, help="a nearest track this far or farther is beside its "
                                                               "target, not on it (m; default 100)")
    a = ap.parse_args()
    res = run_figures(a.scenario, a.methods, a.case, a.blocks)
    for name, r in res.items():
        g, near = r["gospa_m"], r["nearest_m"]
        ghost = (near >= a.near) & np.isfinite(near)
        print(f"\n{name}: GOSPA over {len(g)} runs: mean {np.sqrt(np.mean(g ** 2)):.1f} m (root of the mean square), "
              f"median run {np.median(g):.1f} m; runs with a target held beside it ({a.near:g} m or more): "
              f"{int(ghost.any(1).sum())}")
        print("| run | GOSPA (m) | per target: median distance to the nearest track (m) |")
        print("|---:|---:|---|")
        for i in range(len(g)):
            cells = " / ".join("-" if not np.isfinite(v) else f"{v:.0f}" + ("*" if ghost[i, t] else "")
                               for t, v in enumerate(near[i]))
            print(f"| {i} | {g[i]:.1f} | {cells} |")


if __name__ == "__main__":
    main()
