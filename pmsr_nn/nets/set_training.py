"""``pmsr train`` for the set tracker (:mod:`.set_tracker`; a config with ``kind: set_tracker``).

Every step draws a fresh batch of scenes of ``model.window`` scans (:class:`~.scene_data.SceneSampler`:
formations, crossings, independent tracks, Pd and clutter drawn per batch) and their detections;
the network answers with a set of states at each window's last scan, scored by
:func:`~.set_tracker.set_loss` against the targets there. Validation reads fixed scenes of its own
seed and logs the loss and the GOSPA parts (:func:`gospa_parts`) of the predictions that say they
exist. Lightning on ``accelerator`` (``auto``: a GPU where there is one). Run folder as for every
``pmsr train``; ``tracker.pt`` is what kind ``set_tracker`` reads.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from ..config import from_dict, load_yaml, require, to_dict
from .scene_data import FlyOptimConfig, SceneConfig, SceneSampler, fit_on_the_fly, resolve_recipe_path, start_run
from .set_tracker import SetTracker, SetTrackerConfig, detection_tokens, set_loss


@dataclass(frozen=True)
class SetOptimConfig(FlyOptimConfig):
    """:class:`~.scene_data.FlyOptimConfig`, the set loss's cut-off (m) and which matched queries
    its existence term calls present (:func:`~.set_tracker.set_loss`)."""

    lr: float = 3.0e-4
    batch_size: int = 64
    steps: int = 2000
    val_every: int = 250
    val_scenes: int = 256
    cutoff_m: float = 500.0
    existence: str = "matched"

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.cutoff_m > 0, f"optim: cutoff_m must be positive, got {self.cutoff_m}")
        require(self.existence in ("matched", "near"), f"optim: existence must be 'matched' (every query the "
                                                       f"matching pairs with a target) or 'near' (those within "
                                                       f"cutoff_m), got {self.existence!r}")


@dataclass(frozen=True)
class SetTrainConfig:
    """A ``kind: set_tracker`` training config (``train/set_tracker.yaml``); ``scenes.window`` is
    the network's ``model.window``; ``init``: a set tracker checkpoint whose weights training
    starts from (fine-tuning; same sensors and network size), else random weights."""

    kind: str
    name: str = "set_tracker"
    seed: int = 0
    recipe: str = "../datasets/fitee2023_ca.yaml"
    accelerator: str = "auto"
    threads: int | None = None
    init: str | None = None
    scenes: SceneConfig = SceneConfig(window=6, targets=(1, 5))
    model: SetTrackerConfig = SetTrackerConfig()
    optim: SetOptimConfig = SetOptimConfig()

    def __post_init__(self) -> None:
        require(self.kind == "set_tracker", f"kind must be set_tracker, got {self.kind!r}")
        require(self.scenes.window == self.model.window, f"scenes.window ({self.scenes.window}) must be the network's "
                                                         f"model.window ({self.model.window})")
        require(self.accelerator in ("auto", "cpu", "gpu", "cuda"), f"accelerator must be auto, cpu or gpu, got "
                                                                     f"{self.accelerator!r}")


def load_set_config(path, overrides=()) -> SetTrainConfig:
    from .train_config import apply_overrides

    cfg = from_dict(SetTrainConfig, apply_overrides(load_yaml(path), list(overrides)), where="train config")
    return replace(cfg, recipe=resolve_recipe_path(cfg.recipe, path))


def gospa_parts(pos: torch.Tensor, p: torch.Tensor, true_pos: torch.Tensor, cutoff_m: float,
                threshold: float = 0.5) -> tuple[float, int, int, int]:
    """GOSPA (alpha 2, order 2) parts of one window's predictions that say they exist (``p >=
    threshold``; ``pos (Q, 2)``) against ``true_pos (N, 2)``: the summed squared distance of the
    assigned pairs nearer than ``cutoff_m``, and how many were assigned, missed and false."""
    est = pos[p >= threshold].double().cpu().numpy()
    tru = true_pos.double().cpu().numpy()
    if len(est) == 0 or len(tru) == 0:
        return 0.0, 0, len(tru), len(est)
    d = np.linalg.norm(est[:, None] - tru[None], axis=-1)
    r, c = linear_sum_assignment(np.minimum(d, cutoff_m) ** 2)
    near = d[r, c] < cutoff_m
    return float((d[r, c][near] ** 2).sum()), int(near.sum()), len(tru) - int(near.sum()), len(est) - int(near.sum())


def make_module(cfg: SetTrainConfig, sampler: SceneSampler):
    import lightning.pytorch as pl

    class SetModule(pl.LightningModule):
        def __init__(self):
            super().__init__()
            self.net = SetTracker(cfg.model, sampler.model, sampler.dt, sampler.motion.dim_x)

        def _batch(self, seed):
            scans, truth, _, _, _ = sampler.draw(seed, cfg.optim.batch_size)
            toks = detection_tokens(scans.z, scans.valid, sampler.model, cfg.model).to(self.device)
            origin = scans.origin.reshape(len(truth), -1).to(self.device)
            last = truth[:, -1].to(self.device)
            alive = torch.ones(last.shape[:2], dtype=torch.bool, device=self.device)
            return toks, origin, last[..., [0, 3]], last[..., [1, 4]], alive

        def training_step(self, step, _):
            toks, origin, tp, tv, alive = self._batch((cfg.seed, int(step)))
            loss, parts = set_loss(self.net(toks), tp, tv, alive, cfg.optim.cutoff_m, origin, existence=cfg.optim.existence)
            self.log("train/loss", loss, batch_size=cfg.optim.batch_size)
            for key in ("state", "existence", "association"):
                self.log(f"train/{key}", parts[key], batch_size=cfg.optim.batch_size)
            return loss

        def validation_step(self, i, _):
            toks, origin, tp, tv, alive = self._batch((cfg.seed, 1_000_000, int(i)))
            out = self.net(toks)
            loss, _ = set_loss(out, tp, tv, alive, cfg.optim.cutoff_m, origin, existence=cfg.optim.existence)
            p = torch.sigmoid(out.logit)
            parts = [gospa_parts(out.pos[w], p[w], tp[w], cfg.optim.cutoff_m) for w in range(len(p))]
            sq, n_ok, missed, false = (sum(x[j] for x in parts) for j in range(4))
            W = len(parts)
            c2 = cfg.optim.cutoff_m**2 / 2
            self.log("val/loss", loss, batch_size=W)
            self.log("val/gospa_m", math.sqrt((sq + c2 * (missed + false)) / W), batch_size=W)
            self.log("val/gospa_empty_set_m", math.sqrt(c2 * sum(len(t) for t in tp) / W), batch_size=W)  # "no target"
            self.log("val/matched_rmse_m", math.sqrt(sq / max(n_ok, 1)), batch_size=W)
            self.log("val/missed_per_window", missed / W, batch_size=W)
            self.log("val/false_per_window", false / W, batch_size=W)

        def configure_optimizers(self):
            opt = torch.optim.AdamW(self.net.parameters(), lr=cfg.optim.lr, weight_decay=1e-4)
            sched = torch.optim.lr_scheduler.OneCycleLR(opt, cfg.optim.lr, total_steps=cfg.optim.steps, pct_start=0.05)
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    return SetModule()


def start_from(net, path: str, sampler: SceneSampler) -> None:
    """Load the weights of the set checkpoint at ``path`` into ``net``; one line if its sensors or
    network size differ."""
    from ..errors import CheckpointError
    from .checkpoint import check_detection_sensors
    from .set_inference import load_set_checkpoint

    ck = load_set_checkpoint(path)
    m = sampler.model
    check_detection_sensors(ck.meta, m.geometry.to_dict(), m.components, m.noise_std, sampler.dt,
                            sampler.motion.dim_x, f"init {path}")
    shapes = {k: tuple(v.shape) for k, v in net.state_dict().items()}
    if shapes != {k: tuple(v.shape) for k, v in ck.net.state_dict().items()}:
        raise CheckpointError(f"init {path}: its network has another size than model (d_model, heads, layers, "
                              "queries)")
    net.load_state_dict(ck.net.state_dict())


def train_set(cfg: SetTrainConfig, out: str | Path, progress: bool = True) -> dict:
    """Train ``cfg`` into the new run folder ``out``; returns the metrics (also in metrics.json)."""
    from .torch_settings import restored_torch_settings

    with restored_torch_settings(cfg.threads):
        return _train_set(cfg, out, progress)


def _train_set(cfg: SetTrainConfig, out: str | Path, progress: bool) -> dict:
    import lightning.pytorch as pl

    from ..outputs import write_marker
    from .set_inference import save_set_checkpoint, set_metadata

    out = Path(out)
    if cfg.accelerator in ("gpu", "cuda") and not torch.cuda.is_available():
        from ..errors import ConfigError

        raise ConfigError(f"accelerator={cfg.accelerator}: no CUDA GPU is available on this machine (use auto or cpu)")
    start_run(out, cfg, cfg.recipe)
    sampler = SceneSampler(cfg.recipe, cfg.scenes)
    pl.seed_everything(cfg.seed, verbose=False)
    module = make_module(cfg, sampler)
    if cfg.init is not None:
        start_from(module.net, cfg.init, sampler)
    o = cfg.optim
    trainer, ckpt, seconds = fit_on_the_fly(module, out, o.steps, o.val_every, o.val_batches,
                                            o.gradient_clip_val, o.max_time_minutes, cfg.accelerator, progress=progress)
    meta = set_metadata(cfg.model, sampler.model, sampler.dt, sampler.motion.dim_x, seed=cfg.seed,
                        steps=int(trainer.global_step), config=to_dict(cfg), device=str(trainer.strategy.root_device))
    save_set_checkpoint(out / "tracker.pt", meta, module.net.cpu())
    metrics = {"steps": int(trainer.global_step), "fit_seconds": seconds, "device": str(trainer.strategy.root_device),
               "best_val_loss": float(ckpt.best_model_score) if ckpt.best_model_score is not None else None,
               "last": {k: float(v) for k, v in trainer.callback_metrics.items()}}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    write_marker(out, "train", state="done")
    if progress:
        last = metrics["last"]
        print(f"trained   {metrics['steps']} steps in {seconds:.0f} s on {metrics['device']}; validation GOSPA "
              f"{last.get('val/gospa_m', float('nan')):.1f} m (matched RMSE {last.get('val/matched_rmse_m', float('nan')):.1f} m, "
              f"missed {last.get('val/missed_per_window', float('nan')):.2f}, false "
              f"{last.get('val/false_per_window', float('nan')):.2f} per window)", flush=True)
    return metrics
