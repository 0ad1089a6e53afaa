"""Benchmark: SI+KF on the CA 1T-3R recipe: position RMSE of the raw SI fixes and of SI+KF, and throughput.

Tracks come from the default recipe (envelope variant) shortened to ``--steps`` samples, seed 0.
The filter uses the recipe's own motion model (CA, jerk PSD of the envelope variant) and each
track's range deviation; it starts from each track's first fix (no prior). RMSE is the root of the
mean squared 2-D position error over tracks and steps from step ``--after`` on. Plain SI
(``refine_steps=0``, its own first-order covariance as R) and SI refined by two Gauss-Newton
steps (maximum-likelihood fixes, the CRB as R) are both measured. Times are the best of
``--repeats`` runs after a warm-up, all tracks batched.

    python benchmarks/bench_si_kf.py --tracks 200 --steps 100 --json OUT.json
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

from pmsr_nn.filters.si_kf import si_kf  # noqa: E402
from pmsr_nn.filters.spherical import range_rows, spherical_interpolation  # noqa: E402
from pmsr_nn.rng import seeded_generator  # noqa: E402
from pmsr_nn.simulation.recipe import TrackRecipe  # noqa: E402
from pmsr_nn.simulation.tracks import build_models, generate_tracks  # noqa: E402


def best_time(fn, repeats: int):
    fn()  # warm-up
    best, out = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracks", type=int, default=200)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--after", type=int, default=10, help="RMSE over steps >= this (filter convergence)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()

    recipe = TrackRecipe()
    recipe = replace(recipe, window=min(recipe.window, args.steps), motion=replace(recipe.motion, steps=args.steps))
    motion, model = build_models(recipe)
    q = recipe.effective_motion().q_psd
    dt = recipe.motion.dt_s
    batch, _ = generate_tracks(recipe, args.tracks, seeded_generator(args.seed))
    z, ns = batch.measurements, batch.noise_std
    truth = batch.states[..., list(motion.pos_idx)]
    rows = range_rows(model)
    after = slice(args.after, None)

    def rmse(est):
        return float(((est - truth)[:, after] ** 2).sum(-1).mean().sqrt())

    n = args.tracks * args.steps
    figures = {"tracks": args.tracks, "steps": args.steps, "after_step": args.after, "seed": args.seed, "q_psd": q,
               "range_std_m_mean": float(ns[:, 0].mean()), "torch_threads": torch.get_num_threads()}
    for name, refine in (("si", 0), ("si_gn2", 2)):
        t_fix, fixes = best_time(lambda: spherical_interpolation(z[..., rows], model.geometry, refine_steps=refine), args.repeats)
        t_all, res = best_time(lambda: si_kf(z, model, motion, dt, q, ns, refine_steps=refine), args.repeats)
        pos = res.x[..., list(motion.pos_idx)]
        fig = {
            "fix_rmse_m": rmse(fixes),
            "kf_rmse_m": rmse(pos),
            "missed_fixes": int(torch.isnan(fixes).any(-1).sum()),
            "rejected_fixes": res.n_rejected,
            "kf_mean_nis": float(res.nis[:, after].mean()),  # chi-square(2): 2 when R is right
            "fix_seconds": t_fix,
            "fix_track_steps_per_s": n / t_fix,
            "si_kf_seconds": t_all,
            "si_kf_track_steps_per_s": n / t_all,
        }
        figures[name] = fig
        print(f"{name}: {args.tracks} tracks x {args.steps} steps; position RMSE after step {args.after}: "
              f"fixes {fig['fix_rmse_m']:.1f} m, SI+KF {fig['kf_rmse_m']:.1f} m (mean NIS {fig['kf_mean_nis']:.2f}, "
              f"{fig['missed_fixes']} missed, {fig['rejected_fixes']} rejected); fixes {n / t_fix / 1e6:.2f} M track-steps/s, "
              f"SI+KF {t_all:.3f} s = {n / t_all / 1e3:.0f} k track-steps/s")
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
