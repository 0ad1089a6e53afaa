"""Benchmark: batched EKF / UKF against filterpy filtering the same tracks one by one.

Tracks come from the CA 1T-3R recipe (envelope variant, 100 samples each). Our filters run on
all tracks at once; filterpy runs on the first ``--reference-tracks`` of them one by one (its time
per track is then scaled to the full count), in the same process, on the same inputs. The
estimates of both on those tracks give ``max_abs_diff_vs_filterpy``.

    python benchmarks/bench_filters.py --tracks 2000 --json OUT.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402
from scenario import ca_scenario  # noqa: E402

from pmsr_nn.filters import SigmaPoints, ekf, ukf  # noqa: E402

DT, Q_PSD, STEPS = 1.0, 1e-7, 100


def scenario(n_tracks: int, device: str):
    sc = ca_scenario(n_tracks, STEPS, device)
    return sc.motion, sc.model, sc.z, sc.R, sc.prior


def filterpy_run(kind, motion, model, z, R, prior, n):
    from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter

    angles = model.angle_mask.numpy()

    def residual(a, b):
        d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        d[angles] = (d[angles] + np.pi) % (2 * np.pi) - np.pi
        return d

    def z_mean(sigmas, wm):
        return np.where(angles, np.arctan2(np.sin(sigmas).T @ wm, np.cos(sigmas).T @ wm), sigmas.T @ wm)

    h = lambda x: model.h(torch.from_numpy(np.asarray(x, dtype=float).ravel())).numpy()
    H = lambda x: model.jacobian(torch.from_numpy(np.asarray(x, dtype=float).ravel())).numpy()
    F, Q = motion.F(DT).numpy(), motion.Q(DT, Q_PSD).numpy()
    out = np.zeros((n, z.shape[1], 6))
    zc, Rc, x0, P0 = z.cpu().numpy(), R.cpu().numpy(), prior.x.cpu().numpy(), prior.P.cpu().numpy()
    t0 = time.perf_counter()
    for b in range(n):
        if kind == "ekf":
            f = ExtendedKalmanFilter(dim_x=6, dim_z=9)
            f.F, f.Q = F, Q
        else:
            pts = MerweScaledSigmaPoints(6, alpha=1.0, beta=2.0, kappa=-3.0)
            f = UnscentedKalmanFilter(dim_x=6, dim_z=9, dt=DT, fx=lambda x, dt: F @ x, hx=h, points=pts,
                                      z_mean_fn=z_mean, residual_z=residual)
            f.Q = Q
        f.x, f.P, f.R = x0[b].copy(), P0[b].copy(), Rc[b]
        for k in range(zc.shape[1]):
            if k > 0:
                f.predict()
            if kind == "ekf":
                f.update(zc[b, k], H, h, residual=residual)
            else:
                f.sigmas_f = pts.sigma_points(f.x, f.P)  # redraw, as our UKF does
                f.update(zc[b, k])
            out[b, k] = np.asarray(f.x).ravel()
    return out, (time.perf_counter() - t0) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracks", type=int, default=10000)
    ap.add_argument("--reference-tracks", type=int, default=50, help="tracks filterpy runs on (its per-track time is scaled)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    motion, model, z, R, prior = scenario(args.tracks, args.device)
    figures = {"tracks": args.tracks, "steps": STEPS, "device": args.device, "torch_threads": torch.get_num_threads()}
    sigma = SigmaPoints(alpha=1.0, beta=2.0, kappa=-3.0)
    runs = {"ekf": lambda: ekf(prior, z, motion, DT, Q_PSD, model, R),
            "ukf": lambda: ukf(prior, z, motion, DT, Q_PSD, model, R, sigma)}
    max_diff = 0.0
    for kind, fn in runs.items():
        if args.device != "cpu":
            fn()  # warm-up on accelerators
        t0 = time.perf_counter()
        res = fn()
        if args.device != "cpu":
            torch.cuda.synchronize()
        ours = time.perf_counter() - t0
        ref, per_track = filterpy_run(kind, motion, model, z, R, prior, args.reference_tracks)
        diff = float(np.abs(res.x[: args.reference_tracks].cpu().numpy() - ref).max())
        max_diff = max(max_diff, diff)
        figures[f"{kind}_seconds"] = ours
        figures[f"{kind}_track_steps_per_s"] = args.tracks * STEPS / ours
        figures[f"{kind}_filterpy_ms_per_track"] = per_track * 1e3
        figures[f"{kind}_speedup_vs_filterpy"] = per_track * args.tracks / ours
        figures[f"{kind}_max_abs_diff_vs_filterpy"] = diff
        print(f"{kind}: {args.tracks} tracks x {STEPS} steps in {ours:.2f} s = {args.tracks * STEPS / ours / 1e6:.2f} M track-steps/s; "
              f"filterpy {per_track * 1e3:.1f} ms/track -> speed-up {figures[f'{kind}_speedup_vs_filterpy']:.0f}x; "
              f"max |diff| {diff:.2e}")
    figures["max_abs_diff_vs_filterpy"] = max_diff
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
