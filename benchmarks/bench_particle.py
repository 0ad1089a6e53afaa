"""Benchmark: batched bootstrap particle filter against the batched UKF on the same tracks.

Tracks come from the CA 1T-3R recipe (envelope variant), as in ``bench_filters.py``; both
filters start from the same perturbed prior (sd 50 m, 3 m/s, 0.05 m/s^2 per axis) with each
track's own noise deviations as ``R``, in the same process. Prints the throughput of each
(track-steps/s; the PF also in particle-steps/s) and the RMSE of position (m) and velocity (m/s)
against the truth over all tracks and steps, plus the PF's mean ESS, resampling rate and the
tracks it lost (a scan beyond reach of every particle; the PF runs with ``on_lost="flag"``, and
``pf_rmse_*_kept`` leave those tracks out for both filters).

    python benchmarks/bench_particle.py --tracks 200 --steps 100 --particles 2000 --json OUT.json

``--q`` is the filters' jerk PSD (m^2/s^5); the default is the truth's (1e-7, the envelope
variant), with which resampled particles are hardly rejuvenated (duplicates stay duplicates).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402
from scenario import ca_scenario  # noqa: E402

from pmsr_nn.filters import SigmaPoints, ukf  # noqa: E402
from pmsr_nn.filters.particle import particle_filter  # noqa: E402
from pmsr_nn.rng import seeded_generator  # noqa: E402

DT = 1.0


def scenario(n_tracks: int, steps: int, device: str):
    sc = ca_scenario(n_tracks, steps, device)
    return sc.motion, sc.model, sc.truth, sc.z, sc.R, sc.prior, sc.q


def rmse(x: torch.Tensor, truth: torch.Tensor, idx) -> float:
    return float(((x[..., list(idx)] - truth[..., list(idx)]) ** 2).sum(-1).mean().sqrt())


def timed(fn, device: str):
    if device != "cpu":
        fn()  # warm-up on accelerators
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    res = fn()
    if device != "cpu":
        torch.cuda.synchronize()
    return res, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracks", type=int, default=200)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--particles", type=int, default=2000)
    ap.add_argument("--q", type=float, default=None, help="filters' jerk PSD, m^2/s^5 (default: the truth's)")
    ap.add_argument("--roughening", type=float, default=0.0, help="PF roughening constant K (0: plain bootstrap)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    motion, model, truth, z, R, prior, q_truth = scenario(args.tracks, args.steps, args.device)
    q = q_truth if args.q is None else args.q
    track_steps = args.tracks * args.steps
    figures = {"tracks": args.tracks, "steps": args.steps, "particles": args.particles, "q_filter": q, "q_truth": q_truth,
               "roughening": args.roughening, "device": args.device, "torch_threads": torch.get_num_threads()}
    sigma = SigmaPoints(alpha=1.0, beta=2.0, kappa=-3.0)
    res_u, t_u = timed(lambda: ukf(prior, z, motion, DT, q, model, R, sigma), args.device)
    gen = lambda: seeded_generator(2, device=args.device if args.device != "cpu" else None)  # noqa: E731
    res_p, t_p = timed(lambda: particle_filter(prior, z, motion, DT, q, model, R, n_particles=args.particles,
                                               generator=gen(), on_lost="flag", roughening=args.roughening), args.device)
    kept = ~res_p.lost.any(1)
    for name, res, t in (("ukf", res_u, t_u), ("pf", res_p, t_p)):
        figures[f"{name}_seconds"] = t
        figures[f"{name}_track_steps_per_s"] = track_steps / t
        figures[f"{name}_rmse_pos_m"] = rmse(res.x, truth, motion.pos_idx)
        figures[f"{name}_rmse_vel_mps"] = rmse(res.x, truth, motion.vel_idx)
        figures[f"{name}_rmse_pos_m_kept"] = rmse(res.x[kept], truth[kept], motion.pos_idx)
        figures[f"{name}_rmse_vel_mps_kept"] = rmse(res.x[kept], truth[kept], motion.vel_idx)
    figures["pf_particle_steps_per_s"] = track_steps * args.particles / t_p
    figures["pf_mean_ess_fraction"] = float(res_p.ess.mean()) / args.particles
    figures["pf_resampled_fraction"] = float(res_p.resampled.double().mean())
    figures["pf_lost_tracks"] = int((~kept).sum())
    for name, res, t in (("ukf", res_u, t_u), ("pf", res_p, t_p)):
        label = name if name == "ukf" else f"pf ({args.particles} particles)"
        extra = (f" ({figures['pf_particle_steps_per_s'] / 1e6:.2f} M particle-steps/s, {t_p / t_u:.0f}x the UKF's time)"
                 if name == "pf" else "")
        print(f"{label}: {args.tracks} tracks x {args.steps} steps in {t:.2f} s = {track_steps / t:,.0f} track-steps/s{extra}; "
              f"RMSE pos {figures[f'{name}_rmse_pos_m']:.2f} m, vel {figures[f'{name}_rmse_vel_mps']:.3f} m/s "
              f"(tracks the PF kept: {figures[f'{name}_rmse_pos_m_kept']:.2f} m, {figures[f'{name}_rmse_vel_mps_kept']:.3f} m/s)")
    print(f"pf: mean ESS {figures['pf_mean_ess_fraction']:.1%} of the particles, resampled at "
          f"{figures['pf_resampled_fraction']:.1%} of track-steps, lost {figures['pf_lost_tracks']} of {args.tracks} tracks")
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
