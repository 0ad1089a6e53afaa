"""Study: the classical single-target baselines against both forms of the PCRB on the same tracks.

Draws tracks of the CA 1T-3R recipe, runs every baseline on the same measurements (filters with
the matched motion model and each track's own noise deviations), and prints per-method position
and velocity RMSE after a burn-in beside the information-averaged and per-trajectory bounds
(filtering bounds for filters, smoothing bounds for smoothers). Writes ``results.json`` and
``rmse.png`` to ``--out``.

    python evaluate/baselines_vs_bounds.py --tracks 200 --steps 100 --out runs/baselines_vs_bounds

The particle filter is the bootstrap filter with roughening (K = 0.2; without it the filter
collapses under the envelope variant's q = 1e-7); it needs ~10^4 particles here to come near the
Gaussian filters, so ``--particles`` sets the cost of the whole study.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

from pmsr_nn.bounds import pcrb
from pmsr_nn.filters import Gaussian, ekf, particle_filter, rts_smoother, si_kf, ukf, unscented_rts_smoother
from pmsr_nn.metrics import pooled_rmse, rmse_over_time
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.recipe import TrackRecipe, load_recipe
from pmsr_nn.simulation.tracks import build_models, generate_tracks


def bound_rmse(P: torch.Tensor, idx, burn_in: int) -> float:
    return float(torch.diagonal(P[burn_in:], dim1=-2, dim2=-1)[..., list(idx)].sum(-1).mean().sqrt())


def run(recipe: TrackRecipe, tracks: int, steps: int, burn_in: int, particles: int, seed: int) -> dict:
    recipe = replace(recipe, window=min(recipe.window, steps), motion=replace(recipe.motion, steps=steps))
    motion, model = build_models(recipe)
    q, dt = recipe.effective_motion().q_psd, recipe.motion.dt_s
    batch, _ = generate_tracks(recipe, tracks, seeded_generator(seed, 1))
    truth, z, R = batch.states, batch.measurements, model.R(batch.noise_std)
    sd = recipe.initiation_prior_sd()
    P0 = torch.diag(sd**2)
    x0 = truth[:, 0] + torch.randn(tracks, 6, generator=seeded_generator(seed, 2), dtype=torch.float64) * sd
    prior = Gaussian(x0, P0.expand(tracks, 6, 6).clone())
    F, Q = motion.F(dt), motion.Q(dt, q)

    estimates, seconds = {}, {}

    def timed(name, fn):
        t0 = time.perf_counter()
        estimates[name] = fn()
        seconds[name] = time.perf_counter() - t0
        print(f"  {name:<16} {seconds[name]:7.2f} s", file=sys.stderr)

    timed("EKF", lambda: ekf(prior, z, motion, dt, q, model, R))
    timed("UKF", lambda: ukf(prior, z, motion, dt, q, model, R))
    timed("EKF + RTS", lambda: rts_smoother(estimates["EKF"].x, estimates["EKF"].P, motion, dt, q))
    timed("UKF + URTS", lambda: unscented_rts_smoother(estimates["UKF"].x, estimates["UKF"].P, lambda s: s @ F.T, Q))
    timed("SI+KF", lambda: si_kf(z, model, motion, dt, q, noise_std=batch.noise_std, prior=prior))
    timed("SI+GN+KF", lambda: si_kf(z, model, motion, dt, q, noise_std=batch.noise_std, prior=prior, refine_steps=2))
    timed(f"PF {particles} rough.", lambda: particle_filter(prior, z, motion, dt, q, model, R, n_particles=particles,
                                                             generator=seeded_generator(seed, 3), roughening=0.2,
                                                             on_lost="flag"))
    t0 = time.perf_counter()
    bounds = {form: pcrb(truth, motion, dt, q, model, R, P0, form=form) for form in ("information_averaged", "per_trajectory")}
    seconds["PCRB (both forms)"] = time.perf_counter() - t0

    pos, vel = motion.pos_idx, motion.vel_idx
    per_track = bounds["per_trajectory"]
    rows = []
    for name, est in estimates.items():
        smoother = "RTS" in name
        # Paired per-track comparison with the per-trajectory bound of the matching kind: the
        # ratio of each track's time-averaged squared position error to its own bound.
        own = per_track.per_track_position_smoothing if smoother else per_track.per_track_position
        err2 = ((est.x - truth)[:, burn_in:][..., list(pos)] ** 2).sum(-1).mean(1)
        ratio = err2 / (own[:, burn_in:] ** 2).mean(1)
        rows.append({
            "method": name,
            "kind": "smoother" if smoother else "filter",
            "position_rmse_m": pooled_rmse(est.x, truth, pos, burn_in),
            "velocity_rmse_mps": pooled_rmse(est.x, truth, vel, burn_in),
            "mse_over_per_track_bound": float(ratio.mean()),
            "mse_over_per_track_bound_se": float(ratio.std() / len(ratio) ** 0.5),
            "seconds": seconds[name],
        })
        if hasattr(est, "lost"):
            rows[-1]["lost_tracks"] = int(est.lost.any(1).sum())
    for form, b in bounds.items():
        for which in ("filtering", "smoothing"):
            rows.append({
                "method": f"PCRB {form.replace('_', '-')} ({which})",
                "kind": "bound",
                "position_rmse_m": bound_rmse(getattr(b, which), pos, burn_in),
                "velocity_rmse_mps": bound_rmse(getattr(b, which), vel, burn_in),
                "seconds": seconds["PCRB (both forms)"],
            })
    curves = {name: rmse_over_time(est.x, truth, pos).tolist() for name, est in estimates.items()}
    for form, b in bounds.items():
        curves[f"PCRB {form} (filtering)"] = b.position_rmse().tolist()
        curves[f"PCRB {form} (smoothing)"] = b.position_rmse("smoothing").tolist()
    return {
        "variant": recipe.variant, "tracks": tracks, "steps": steps, "burn_in": burn_in, "seed": seed,
        "q_psd": q, "prior_sd": sd.tolist(), "particles": particles, "rows": rows, "curves": curves,
    }


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(6.5 * len(results), 5.5), squeeze=False)
    colours = plt.get_cmap("tab20").colors
    for ax, res in zip(axes[0], results):
        for i, (name, curve) in enumerate(res["curves"].items()):
            style = "--" if "PCRB" in name else "-"
            ax.semilogy(curve, style, label=name, lw=1.3, color=colours[(2 * i) % 20 + (i >= 10)])
        ax.set(title=f"{res['variant']} variant, {res['tracks']} tracks", xlabel="step", ylabel="position RMSE (m)")
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def table(res: dict) -> str:
    lines = [f"{res['variant']} variant: {res['tracks']} tracks x {res['steps']} steps, RMSE after step {res['burn_in']}",
             f"{'method':<44}{'pos (m)':>10}{'vel (m/s)':>11}{'MSE/own bound':>17}{'time (s)':>10}"]
    for r in res["rows"]:
        ratio = (f"{r['mse_over_per_track_bound']:.3f} +- {r['mse_over_per_track_bound_se']:.3f}"
                 if "mse_over_per_track_bound" in r else "")
        lines.append(f"{r['method']:<44}{r['position_rmse_m']:>10.2f}{r['velocity_rmse_mps']:>11.3f}{ratio:>17}{r['seconds']:>10.2f}")
    lines.append("MSE/own bound: mean over tracks of (time-averaged squared position error) / (that track's own "
                 "per-trajectory bound, filtering or smoothing), +- its standard error")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--recipe", help="recipe YAML (default: the built-in FITEE 2023 CA recipe)")
    p.add_argument("--variants", nargs="+", default=["envelope", "literal"], choices=["envelope", "literal"])
    p.add_argument("--tracks", type=int, default=200)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--burn-in", type=int, default=20)
    p.add_argument("--particles", type=int, default=2000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--out", default="runs/baselines_vs_bounds")
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    if not 0 <= a.burn_in < a.steps:
        p.error("--burn-in must be in [0, --steps)")
    base = load_recipe(a.recipe) if a.recipe else TrackRecipe()
    results = []
    for variant in a.variants:
        print(f"{variant}:", file=sys.stderr)
        results.append(run(replace(base, variant=variant), a.tracks, a.steps, a.burn_in, a.particles, a.seed))
        print(table(results[-1]) + "\n")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"date": datetime.date.today().isoformat(), "machine": platform.processor() or platform.machine(),
            "threads": torch.get_num_threads(), "command": "python evaluate/baselines_vs_bounds.py " + " ".join(sys.argv[1:])}
    (out / "results.json").write_text(json.dumps({"meta": meta, "results": results}, indent=1))
    plot(results, out / "rmse.png")
    print(f"wrote {out / 'results.json'} and {out / 'rmse.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
