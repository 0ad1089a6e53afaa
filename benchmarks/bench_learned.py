"""Benchmark: learned trackers, training throughput and inference against the batched UKF.

Training: windows per second of one optimiser step (forward, backward, Adam) on batches of
``--batch`` windows of ``--window`` scans, for MDFNN (Table 2), DFNN and the LSTM (256 units),
after warm-up steps. Inference: track-steps per second of an MDFNN tracking whole sequences of
the CA recipe (sliding windows, spliced) against the batched UKF filtering the *same* tracks in
the same process; the ratio is the figure to compare across machines.

    python benchmarks/bench_learned.py --json benchmarks/results/bench_learned.json
    python benchmarks/bench_learned.py --device cuda --json benchmarks/results/bench_learned_gpu.json
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

from pmsr_nn.filters import Gaussian, ukf  # noqa: E402
from pmsr_nn.nets.config import ModelConfig  # noqa: E402
from pmsr_nn.nets.inference import Tracker  # noqa: E402
from pmsr_nn.nets.networks import build_network  # noqa: E402
from pmsr_nn.rng import seeded_generator  # noqa: E402
from pmsr_nn.simulation.recipe import TrackRecipe  # noqa: E402
from pmsr_nn.simulation.tracks import build_models, generate_tracks  # noqa: E402

MODELS = {"MDFNN": ModelConfig(), "DFNN": ModelConfig(kind="dfnn"), "LSTM-256": ModelConfig(kind="rnn"),
          "MDFNN-local": ModelConfig(filter_taps="per_channel", inputs="local_fixes", output="residual"),
          "MDFNN-local-compact": ModelConfig(hidden=(128, 96, 128), filter_taps="per_channel", inputs="local_fixes",
                                             output="residual"),
          "KalmanNet": ModelConfig(kind="kalmannet", rnn_hidden=64, inputs="measurements_and_fixes", output="residual")}
"""Table 2's MDFNN (paper inputs, then window-local inputs and residual output), the compact local
MDFNN of ``models/mdfnn_local.yaml``, the DFNN, the LSTM and the KalmanNet-style tracker of
``models/kalmannet.yaml``."""


def _kalmannet(cfg: ModelConfig):
    """A KalmanNet for the built-in recipe (its scales do not change the cost)."""
    from pmsr_nn.nets.kalmannet import KalmanNetTracker

    recipe = TrackRecipe()
    _, model = build_models(recipe)
    return KalmanNetTracker(cfg, model, recipe.motion.dt_s, torch.ones(9), torch.ones(6))


def sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def training_throughput(cfg: ModelConfig, batch: int, window: int, steps: int, device: str, precision: str) -> float:
    torch.manual_seed(0)
    net = (_kalmannet(cfg) if cfg.kind == "kalmannet" else build_network(cfg, 9, 6)).float().to(device)
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    z = torch.rand(batch, window, cfg.input_dim(9, 6), device=device) * 2 - 1
    if cfg.kind == "kalmannet":  # measurements of a real scene (SI) and their state fixes
        recipe = TrackRecipe()
        _, model = build_models(recipe)
        b, _ = generate_tracks(recipe.with_overrides(tracks=20), 4, seeded_generator(0))
        from pmsr_nn.filters.fixes import state_fixes

        zz = b.measurements.unfold(1, window, window).transpose(-1, -2).reshape(-1, window, 9)
        zz = zz[torch.arange(batch) % len(zz)]
        z = torch.cat([zz, state_fixes(zz, model, 6)], -1).float().to(device)
    x = torch.rand(batch, window, 6, device=device) * 2 - 1
    autocast = torch.autocast(device_type="cuda" if device.startswith("cuda") else "cpu", dtype=torch.bfloat16,
                              enabled=precision == "bf16")

    def step():
        with autocast:
            loss = ((net(z).float() - x) ** 2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    for _ in range(3):
        step()
    sync(device)
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    sync(device)
    return batch * steps / (time.perf_counter() - t0)


def inference_vs_ukf(tracks: int, steps: int, device: str, checkpoint: str | None) -> dict:
    recipe = TrackRecipe()
    recipe = replace(recipe, motion=replace(recipe.motion, steps=steps), window=min(recipe.window, steps))
    motion, model = build_models(recipe)
    batch, _ = generate_tracks(recipe, tracks, seeded_generator(0))
    z = batch.measurements
    if checkpoint:
        tracker = Tracker.load(checkpoint, device=device)
    else:  # throughput does not depend on the weights: an untrained Table-2 MDFNN
        from pmsr_nn.data.normalise import RunningMinMax

        mm_z, mm_x = RunningMinMax(9), RunningMinMax(6)
        mm_z.update(z.numpy())
        mm_x.update(batch.states.numpy())
        meta = {"window": recipe.window, "dim_z": 9, "dim_x": 6,
                "normalisation": {"measurements": mm_z.scaler().to_dict(), "states": mm_x.scaler().to_dict()}}
        tracker = Tracker(build_network(ModelConfig(), 9, 6).float().to(device), meta, ModelConfig())
    tracker.track(z[:2])  # warm-up
    sync(device)
    t0 = time.perf_counter()
    tracker.track(z)
    sync(device)
    t_net = time.perf_counter() - t0
    sd = recipe.initiation_prior_sd()
    prior = Gaussian(batch.states[:, 0], torch.diag(sd**2).expand(tracks, 6, 6).clone())
    q, dt = recipe.effective_motion().q_psd, recipe.motion.dt_s
    R = model.R(batch.noise_std)
    t0 = time.perf_counter()
    ukf(prior, z, motion, dt, q, model, R)
    t_ukf = time.perf_counter() - t0
    n = tracks * steps
    return {"tracks": tracks, "steps": steps, "mdfnn_track_steps_per_s": n / t_net, "ukf_track_steps_per_s": n / t_ukf,
            "mdfnn_over_ukf_speed": t_ukf / t_net, "mdfnn_device": device, "ukf_device": "cpu (float64)",
            "stride": tracker.default_stride(), "window": tracker.window}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--window", type=int, default=100)
    p.add_argument("--steps", type=int, default=10, help="timed optimiser steps per model")
    p.add_argument("--precision", choices=["32", "bf16", "both"], default="both",
                   help="training precision; both: every model in float32 and in bf16 autocast, in the same run")
    p.add_argument("--tracks", type=int, default=200)
    p.add_argument("--track-steps", type=int, default=1000)
    p.add_argument("--checkpoint", help="MDFNN checkpoint for the inference timing (default: untrained Table-2 MDFNN)")
    p.add_argument("--threads", type=int)
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    figures = {"device": a.device, "threads": torch.get_num_threads(), "batch": a.batch, "window": a.window,
               "precision": a.precision, "training_windows_per_s": {}}
    if a.device.startswith("cuda"):
        figures["gpu"] = torch.cuda.get_device_name(0)
    precisions = ["32", "bf16"] if a.precision == "both" else [a.precision]
    for name, cfg in MODELS.items():
        for prec in precisions:
            w = training_throughput(cfg, a.batch, a.window, a.steps, a.device, prec)
            key = name if prec == "32" else f"{name} bf16"
            figures["training_windows_per_s"][key] = round(w, 1)
            print(f"train {key:<16} {w:10.1f} windows/s")
    base = figures["training_windows_per_s"].get("MDFNN")
    figures["training_speed_over_mdfnn_fp32"] = {k: round(v / base, 2) for k, v in figures["training_windows_per_s"].items()} if base else None
    inf = inference_vs_ukf(a.tracks, a.track_steps, a.device, a.checkpoint)
    figures["inference"] = inf
    print(f"track MDFNN {inf['mdfnn_track_steps_per_s']:.3g} track-steps/s, UKF {inf['ukf_track_steps_per_s']:.3g} "
          f"track-steps/s: MDFNN {inf['mdfnn_over_ukf_speed']:.2f}x the UKF ({a.tracks} tracks x {a.track_steps} scans)")
    write_figures(figures, a.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
