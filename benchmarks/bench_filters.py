"""Benchmark: batched EKF / UKF against filterpy filtering the same tracks one by one.

Tracks come from the CA 1T-3R recipe (envelope variant, 100 samples each). Our filters run on
all tracks at once; filterpy runs on the first ``--reference-tracks`` of them one by one (its time
per track is then scaled to the full count), in the same process, on the same inputs. The
estimates of both on those tracks give ``max_abs_diff_vs_filterpy``.

filterpy's measurement function and Jacobian are written here in numpy (:class:`NumpyBistatic`),
not our ``MeasurementModel``: the reference must not speed up or slow down with the code it
measures (until issue 37 it called our torch model, so a faster ``h`` of ours lowered our ratio).
Our filters are timed as the fastest of ``--repeats`` calls after a warm-up (this machine's load
varies; the minimum is the least disturbed), filterpy once over its tracks.

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


class NumpyBistatic:
    """Bistatic range, range-rate and azimuth of a 2-D CA state ``[x, vx, ax, y, vy, ay]`` for
    pairs ``tx, rx (N, 2)``, component-major (``[r_1..r_N, rdot_1..rdot_N, phi_1..phi_N]``), and
    its analytic Jacobian: the filterpy reference's own model, independent of ``pmsr_nn``."""

    def __init__(self, tx: np.ndarray, rx: np.ndarray):
        self.tx, self.rx = tx, rx

    def h(self, x: np.ndarray) -> np.ndarray:
        p, v = np.array([x[0], x[3]]), np.array([x[1], x[4]])
        dt, dr = p - self.tx, p - self.rx
        nt, nr = np.linalg.norm(dt, axis=1), np.linalg.norm(dr, axis=1)
        rate = (dt / nt[:, None] + dr / nr[:, None]) @ v
        return np.concatenate([nt + nr, rate, np.arctan2(dr[:, 0], dr[:, 1])])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        p, v = np.array([x[0], x[3]]), np.array([x[1], x[4]])
        dt, dr = p - self.tx, p - self.rx
        nt, nr = np.linalg.norm(dt, axis=1), np.linalg.norm(dr, axis=1)
        ut, ur = dt / nt[:, None], dr / nr[:, None]
        d_rate_dp = ((v - ut * (ut @ v)[:, None]) / nt[:, None] + (v - ur * (ur @ v)[:, None]) / nr[:, None])
        rho2 = (dr ** 2).sum(1)
        N = len(nt)
        J = np.zeros((3 * N, 6))
        J[:N, [0, 3]] = ut + ur
        J[N:2 * N, [0, 3]] = d_rate_dp
        J[N:2 * N, [1, 4]] = ut + ur
        J[2 * N:, 0], J[2 * N:, 3] = dr[:, 1] / rho2, -dr[:, 0] / rho2
        return J


def reference_model(model) -> NumpyBistatic:
    """The numpy model of ``model``'s geometry; refuses a model it does not describe."""
    if model.components != ("range", "range_rate", "azimuth") or model.layout != "component" or model.pos_idx != (0, 3):
        raise SystemExit(f"bench_filters: the numpy reference models 2-D CA range / range-rate / azimuth, got "
                         f"{model.components} {model.layout} {model.pos_idx}")
    g = model.geometry
    return NumpyBistatic(g.pair_tx_positions().numpy(), g.pair_rx_positions().numpy())


def filterpy_run(kind, motion, model, z, R, prior, n):
    from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter

    angles = model.angle_mask.numpy()
    ref = reference_model(model)

    def residual(a, b):
        d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
        d[angles] = (d[angles] + np.pi) % (2 * np.pi) - np.pi
        return d

    def z_mean(sigmas, wm):
        return np.where(angles, np.arctan2(np.sin(sigmas).T @ wm, np.cos(sigmas).T @ wm), sigmas.T @ wm)

    h = lambda x: ref.h(np.asarray(x, dtype=float).ravel())
    H = lambda x: ref.jacobian(np.asarray(x, dtype=float).ravel())
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
    ap.add_argument("--repeats", type=int, default=5, help="calls of our filters timed (the fastest counts)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    motion, model, z, R, prior = scenario(args.tracks, args.device)
    figures = {"tracks": args.tracks, "steps": STEPS, "device": args.device, "torch_threads": torch.get_num_threads()}
    sigma = SigmaPoints(alpha=1.0, beta=2.0, kappa=-3.0)
    runs = {"ekf": lambda: ekf(prior, z, motion, DT, Q_PSD, model, R),
            "ukf": lambda: ukf(prior, z, motion, DT, Q_PSD, model, R, sigma)}
    ref = reference_model(model)
    xs = prior.x[: args.reference_tracks].cpu().double()
    model_diff = max(float(np.abs(model.h(x).numpy() - ref.h(x.numpy())).max()) for x in xs)
    jac_diff = max(float(np.abs(model.jacobian(x).numpy() - ref.jacobian(x.numpy())).max()) for x in xs)
    figures.update(reference_h_max_abs_diff=model_diff, reference_jacobian_max_abs_diff=jac_diff, repeats=args.repeats)
    print(f"numpy reference model against ours at {len(xs)} priors: |h| diff {model_diff:.1e}, |H| diff {jac_diff:.1e}")
    max_diff = 0.0
    for kind, fn in runs.items():
        fn()  # warm-up
        times = []
        for _ in range(max(1, args.repeats)):
            t0 = time.perf_counter()
            res = fn()
            if args.device != "cpu":
                torch.cuda.synchronize()
            times.append(time.perf_counter() - t0)
        ours = min(times)
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
