"""Study: learned trackers against the UKF, the EKF and the filtering PCRB on the same test tracks.

Tracks the test split of a dataset with every given checkpoint (whole 1000-scan sequences, by
sliding windows), runs the EKF and UKF (matched CA model, each track's own noise deviations,
a coarse first fix) on the same measurements, and computes on the same true trajectories

* the per-trajectory filtering PCRB (every past scan; what a causal tracker is compared with),
* the per-trajectory smoothing PCRB (for a tracker that looks ahead), and
* for each learned tracker, the *finite-memory* bound: the filtering bound of only the scans the
  network reads at each step (an MDFNN of order M reads 2 (M - 1) + 1 scans, a DFNN one; the
  RNN, spliced with stride s, at least window - s + 1), with the spread of the training states
  as prior. No network can beat its finite-memory bound; the gap between that bound and the
  ordinary filtering bound is what its architecture gives away.

RMSE is Eq. 31 (per step over the tracks) averaged over the steps from the end of the first window.

    python evaluate/learned_vs_bounds.py --tracker MDFNN=runs/mdfnn/tracker.pt \\
        --tracker DFNN=runs/dfnn/tracker.pt --tracker RNN=runs/rnn/tracker.pt \\
        --out evaluate/results/learned_vs_bounds
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from pmsr_nn.bounds import finite_memory_pcrb, pcrb
from pmsr_nn.data.store import open_dataset
from pmsr_nn.filters import Gaussian, ekf, ukf
from pmsr_nn.metrics import position_columns, rmse_over_time, velocity_columns
from pmsr_nn.nets.inference import Tracker
from pmsr_nn.rng import seeded_generator
from pmsr_nn.simulation.tracks import build_models


def run(trackers: dict[str, Tracker], dataset: Path, split: str, seed: int, max_tracks: int | None) -> dict:
    ds = open_dataset(dataset)
    try:
        ids = ds.split_indices(split)[:max_tracks]
        truth = torch.from_numpy(ds.file["states"][ids]).double()
        z = torch.from_numpy(ds.file["measurements"][ids]).double()
        noise_std = torch.from_numpy(ds.file["noise_std"][ids]).double()
        recipe, man = ds.recipe(), ds.manifest
    finally:
        ds.close()
    for name, t in trackers.items():
        t.check_compatible(man["geometry"], man["columns"]["measurements"], man["dt_s"], where=f"dataset {dataset}")
    motion, model = build_models(recipe)
    q, dt = recipe.effective_motion().q_psd, recipe.motion.dt_s
    R = model.R(noise_std)
    B, K, n = truth.shape
    start = max(t.window for t in trackers.values())
    pos, vel = position_columns(n), velocity_columns(n)
    sd = recipe.initiation_prior_sd()
    x0 = truth[:, 0] + torch.randn(B, n, generator=seeded_generator(seed, 2), dtype=torch.float64) * sd
    prior = Gaussian(x0, torch.diag(sd**2).expand(B, n, n).clone())

    est, seconds, causal = {}, {}, {}
    for name, t in trackers.items():
        t0 = time.perf_counter()
        est[name] = t.track(z)
        seconds[name] = time.perf_counter() - t0
        causal[name] = not t.looks_ahead
        print(f"  {name:<8} {seconds[name]:7.2f} s", file=sys.stderr)
    for name, fn in (("EKF", ekf), ("UKF", ukf)):
        t0 = time.perf_counter()
        est[name] = fn(prior, z, motion, dt, q, model, R).x
        seconds[name] = time.perf_counter() - t0
        causal[name] = True
        print(f"  {name:<8} {seconds[name]:7.2f} s", file=sys.stderr)
    t0 = time.perf_counter()
    bound = pcrb(truth, motion, dt, q, model, R, torch.diag(sd**2), form="per_trajectory")
    memory_bounds = {}
    for name, t in trackers.items():
        L = t.memory()
        if L not in memory_bounds:
            memory_bounds[L] = finite_memory_pcrb(truth, motion, dt, q, model, R, t.training_spread(), memory=L)
    seconds["bounds"] = time.perf_counter() - t0

    def avg(curve: torch.Tensor) -> float:
        return float(curve[start:].mean())

    def per_track_ratio(x: torch.Tensor, track_bound: torch.Tensor) -> tuple[float, float]:
        """Mean over tracks of (time-averaged squared position error / time-averaged squared
        bound) and its standard error: below 1 by more than two standard errors is a red flag."""
        err = ((x - truth)[:, start:][..., pos] ** 2).sum(-1).mean(1)
        r = err / (track_bound[:, start:] ** 2).mean(1)
        return float(r.mean()), float(r.std() / len(r) ** 0.5) if len(r) > 1 else float("inf")

    curves = {}
    pcrb_pos, pcrb_vel = bound.position_rmse(), bound.velocity_rmse()
    smooth_pos, smooth_vel = bound.position_rmse("smoothing"), bound.velocity_rmse("smoothing")
    rows = []
    for name, x in est.items():
        p_curve, v_curve = rmse_over_time(x, truth, pos), rmse_over_time(x, truth, vel)
        curves[name] = p_curve.tolist()
        ref_p, ref_v = (pcrb_pos, pcrb_vel) if causal[name] else (smooth_pos, smooth_vel)
        ratio, ratio_se = per_track_ratio(x, bound.per_track_position if causal[name] else bound.per_track_position_smoothing)
        row = {"method": name, "causal": causal[name], "position_rmse_m": avg(p_curve), "velocity_rmse_mps": avg(v_curve),
               "bound": "filtering PCRB" if causal[name] else "smoothing PCRB",
               "bound_position_m": avg(ref_p), "bound_velocity_mps": avg(ref_v), "seconds": seconds[name],
               "steps_below_bound": int((p_curve[start:] < ref_p[start:]).sum()),
               "mse_over_bound": ratio, "mse_over_bound_se": ratio_se,
               "below_bound": ratio + 2 * ratio_se < 1.0}
        row["over_bound"] = row["position_rmse_m"] / row["bound_position_m"]
        if name in trackers:
            L = trackers[name].memory()
            mb = memory_bounds[L]
            row.update({"memory_scans": L, "memory_bound_position_m": avg(mb.position_rmse()),
                        "memory_bound_velocity_mps": avg(mb.velocity_rmse()),
                        "steps_below_memory_bound": int((p_curve[start:] < mb.position_rmse()[start:]).sum())})
            row["over_memory_bound"] = row["position_rmse_m"] / row["memory_bound_position_m"]
            # What Eq. 29 sees: RMSE of each normalised state component. A component the
            # measurements barely inform (acceleration) can dominate the training loss.
            sc = trackers[name].state_scaler
            e_n = sc.normalise(x[:, start:]) - sc.normalise(truth[:, start:])
            row["normalised_rmse_per_component"] = dict(zip(man["columns"]["states"], (e_n**2).mean((0, 1)).sqrt().tolist()))
        rows.append(row)
    curves["PCRB filtering"] = pcrb_pos.tolist()
    curves["PCRB smoothing"] = smooth_pos.tolist()
    for L, mb in memory_bounds.items():
        curves[f"finite-memory bound ({L} scans)"] = mb.position_rmse().tolist()
    bounds = {"filtering": {"position_m": avg(pcrb_pos), "velocity_mps": avg(pcrb_vel)},
              "smoothing": {"position_m": avg(smooth_pos), "velocity_mps": avg(smooth_vel)},
              **{f"memory_{L}": {"position_m": avg(mb.position_rmse()), "velocity_mps": avg(mb.velocity_rmse())}
                 for L, mb in memory_bounds.items()}}
    return {"dataset": str(dataset), "split": split, "tracks": B, "steps": K, "from_step": start, "q_psd": q,
            "variant": recipe.variant, "prior_sd": sd.tolist(), "rows": rows, "bounds": bounds, "curves": curves,
            "checkpoints": {name: t.source for name, t in trackers.items()}}


def training_summary(tracker: Tracker) -> dict | None:
    """From the run's metrics.json (next to the checkpoint): epochs, steps, and how much the
    validation position RMSE still fell over the last quarter of training (a budget-limited run
    is still falling)."""
    path = Path(tracker.source).resolve().parent
    path = path / "metrics.json" if (path / "metrics.json").is_file() else path.parent / "metrics.json"
    if not path.is_file():
        return None
    m = json.loads(path.read_text())
    h = [r["val_pos_rmse_m"] for r in m.get("history", [])]
    if not h:
        return None
    q = max(1, len(h) // 4)
    return {"epochs": m["epochs"], "steps": m["global_step"], "first_val_pos_rmse_m": h[0], "last_val_pos_rmse_m": h[-1],
            "best_val_pos_rmse_m": min(h), "fall_over_last_quarter": 1 - min(h[-q:]) / min(h[:-q] or h),
            "train_windows_per_second": m.get("train_windows_per_second")}


def table(res: dict) -> str:
    lines = [f"{res['tracks']} {res['split']} tracks x {res['steps']} scans ({res['variant']} variant); "
             f"RMSE per step over tracks (Eq. 31), averaged over steps {res['from_step']}..{res['steps'] - 1}",
             "",
             "| method | causal | pos RMSE (m) | vel RMSE (m/s) | / own PCRB | MSE / own PCRB per track | scans read | finite-memory bound (m) | / finite-memory bound |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in res["rows"]:
        flag = " **below its bound: investigate**" if r["below_bound"] else ""
        mem = (f"{r['memory_scans']} | {r['memory_bound_position_m']:.2f} | {r['over_memory_bound']:.2f}"
               if "memory_scans" in r else "all | - | -")
        lines.append(f"| {r['method']} | {'yes' if r['causal'] else 'no (smoother)'} | {r['position_rmse_m']:.2f}{flag} | "
                     f"{r['velocity_rmse_mps']:.3f} | {r['over_bound']:.2f} | {r['mse_over_bound']:.2f} +- {r['mse_over_bound_se']:.2f} | {mem} |")
    b = res["bounds"]
    lines.append(f"| PCRB filtering (per trajectory) | | {b['filtering']['position_m']:.2f} | {b['filtering']['velocity_mps']:.3f} | 1.00 | | all | | |")
    lines.append(f"| PCRB smoothing (per trajectory) | | {b['smoothing']['position_m']:.2f} | {b['smoothing']['velocity_mps']:.3f} | | | all | | |")
    lines.append("own PCRB: filtering for a causal tracker, smoothing for one that looks ahead. MSE / own PCRB per track: "
                 "mean over tracks of time-averaged squared error over time-averaged squared bound, +- standard error; "
                 "flagged when more than two standard errors below 1.")
    return "\n".join(lines)


def plot(res: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 5.5))
    for name, curve in res["curves"].items():
        style = ":" if "memory" in name else "--" if "PCRB" in name else "-"
        ax.semilogy(np.arange(len(curve)), curve, style, lw=1.4, label=name)
    ax.axvline(res["from_step"], color="grey", lw=0.8)
    ax.set(xlabel="scan k", ylabel="position RMSE (m)",
           title=f"learned trackers vs UKF/EKF and bounds, {res['tracks']} {res['split']} tracks")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tracker", action="append", required=True, metavar="NAME=CHECKPOINT")
    p.add_argument("--dataset", type=Path, help="dataset directory (default: the one the first run trained on)")
    p.add_argument("--split", default="test", choices=["train", "val", "test"])
    p.add_argument("--max-tracks", type=int)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=Path("runs/learned_vs_bounds"))
    a = p.parse_args(argv)
    trackers = {}
    for item in a.tracker:
        name, _, path = item.partition("=")
        trackers[name] = Tracker.load(path)
    dataset = a.dataset
    if dataset is None:
        metrics = Path(trackers[next(iter(trackers))].source).parent / "metrics.json"
        dataset = Path(json.loads(metrics.read_text())["dataset"])
    res = run(trackers, dataset, a.split, a.seed, a.max_tracks)
    res["training"] = {name: training_summary(t) for name, t in trackers.items()}
    print(table(res))
    for name, s in res["training"].items():
        if s:
            print(f"{name}: {s['epochs']} epochs / {s['steps']} steps; validation position RMSE {s['first_val_pos_rmse_m']:.1f} -> "
                  f"{s['last_val_pos_rmse_m']:.1f} m (best {s['best_val_pos_rmse_m']:.1f}); fell {100 * s['fall_over_last_quarter']:.1f} % "
                  "over the last quarter of training")
    a.out.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from run_info import run_info

    res["info"] = run_info()
    (a.out / "results.json").write_text(json.dumps(res, indent=1) + "\n")
    plot(res, a.out / "rmse.png")
    print(f"wrote {a.out / 'results.json'} and {a.out / 'rmse.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
