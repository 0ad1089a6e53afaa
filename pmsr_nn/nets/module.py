"""The ``LightningModule`` that trains any tracker network on normalised windows."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import lightning as L
import torch

from ..config import from_dict, require
from ..data.normalise import MinMaxScaler
from .config import ModelConfig
from .networks import build_network
from .representation import Representation


@dataclass(frozen=True)
class OptimConfig:
    """Adam with an optional learning-rate schedule.

    ``schedule``: ``cosine`` anneals from ``lr`` to ``lr * min_lr_ratio`` over ``max_epochs``;
    ``plateau`` divides the rate by 5 after ``plateau_patience`` validations without a better
    position RMSE; ``none`` keeps it fixed. ``loss``: ``normalised`` is Eq. 29 (mean squared
    error of the [-1, 1]-normalised states; with ``output: residual``, of the correction in units
    of the fix's own error); ``physical`` is the mean squared error in SI units (m, m/s, m/s^2),
    which weights position most. ``acceleration_weight`` multiplies the acceleration columns'
    share of either loss: acceleration is barely observable from a few scans, and at weight 1 its
    irreducible error dominates the gradient of a normalised loss (``evaluate/RESULTS.md``).
    """

    lr: float = 1.0e-3
    weight_decay: float = 0.0
    schedule: Literal["cosine", "plateau", "none"] = "cosine"
    min_lr_ratio: float = 0.01
    plateau_patience: int = 3
    loss: Literal["normalised", "physical"] = "normalised"
    acceleration_weight: float = 1.0

    def __post_init__(self) -> None:
        require(0 <= self.acceleration_weight <= 1e3, f"optim.acceleration_weight must be in [0, 1000], got {self.acceleration_weight}")
        require(self.lr > 0, f"optim.lr must be positive, got {self.lr}")
        require(self.weight_decay >= 0, "optim.weight_decay must be non-negative")
        require(0 <= self.min_lr_ratio <= 1, "optim.min_lr_ratio must be in [0, 1]")


class TrackerModule(L.LightningModule):
    """Trains ``build_network(model)`` on ``(z, x)`` windows; validates in physical units.

    Logged: ``train/loss`` and, per validation, ``val/loss``, ``val/pos_rmse_m`` (root mean
    squared Euclidean position error over every sample of every window, m) and
    ``val/vel_rmse_mps``; the same under ``test/`` for the test loop. ``meta`` is the plain-data
    checkpoint block (:func:`pmsr_nn.nets.checkpoint.tracker_metadata`); it rides along in every
    Lightning checkpoint so each one serves inference on its own.
    """

    def __init__(self, model: dict, optim: dict, meta: dict, max_epochs: int = 1):
        super().__init__()
        self.save_hyperparameters()
        self.model_cfg = from_dict(ModelConfig, model, "model")
        self.optim_cfg = from_dict(OptimConfig, optim, "optim")
        self.meta = meta
        self.max_epochs = max_epochs
        # Networks train in float32 whatever torch's default dtype (Lightning's precision then applies).
        rep = Representation.from_meta(meta, self.model_cfg, where="training metadata")
        self.net = build_network(self.model_cfg, meta["dim_z"], meta["dim_x"], rep, meta["dt_s"]).float()
        scaler = MinMaxScaler.from_dict(meta["normalisation"]["states"])
        self.register_buffer("state_lo", scaler.lo.float(), persistent=False)
        self.register_buffer("state_span", scaler.span.float(), persistent=False)
        self.register_buffer("out_scale", rep.scale.float(), persistent=False)
        dim = meta["dim_x"] // 3
        self.pos_idx = [3 * i for i in range(dim)]
        self.vel_idx = [3 * i + 1 for i in range(dim)]
        weights = torch.ones(meta["dim_x"])
        weights[[3 * i + 2 for i in range(dim)]] = self.optim_cfg.acceleration_weight
        self.register_buffer("loss_weights", weights * meta["dim_x"] / weights.sum().clamp_min(1e-12), persistent=False)
        self._sums: dict[str, torch.Tensor] = {}

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.net(z)

    def physical(self, x_norm: torch.Tensor) -> torch.Tensor:
        """Normalised states -> SI units (float32 is ample: 1e-7 relative of 10 km is 1 mm)."""
        return (x_norm + 1.0) * 0.5 * self.state_span + self.state_lo

    def error_si(self, pred: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """Estimation error in SI units of outputs ``pred`` against targets ``y`` (the base cancels)."""
        if self.model_cfg.output == "state":
            return self.physical(pred) - self.physical(y)
        return (pred - y) * self.out_scale

    def _loss(self, pred: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        err = self.error_si(pred, x) if self.optim_cfg.loss == "physical" else pred - x
        sq = err**2
        if self.optim_cfg.acceleration_weight != 1.0:
            sq = sq * self.loss_weights
        return torch.mean(sq)

    def training_step(self, batch, batch_idx):
        z, x = batch
        loss = self._loss(self(z), x)
        self.log("train/loss", loss, prog_bar=True, batch_size=len(z))
        return loss

    def _eval_step(self, batch, stage: str):
        z, x = batch
        pred = self(z)
        self.log(f"{stage}/loss", self._loss(pred, x), batch_size=len(z), sync_dist=True)
        err = self.error_si(pred.float(), x)
        add = {
            "pos": err[..., self.pos_idx].pow(2).sum(-1).sum(),
            "vel": err[..., self.vel_idx].pow(2).sum(-1).sum(),
            "n": torch.tensor(float(err[..., 0].numel()), device=err.device),
        }
        for k, v in add.items():
            self._sums[k] = self._sums.get(k, 0.0) + v.detach().double()

    def _eval_epoch_end(self, stage: str):
        if not self._sums:
            return
        reduce = self.trainer.strategy.reduce
        s = {k: reduce(v, reduce_op="sum") for k, v in self._sums.items()}
        self._sums = {}
        n = s["n"].clamp_min(1.0)
        self.log(f"{stage}/pos_rmse_m", torch.sqrt(s["pos"] / n).float(), prog_bar=True)
        self.log(f"{stage}/vel_rmse_mps", torch.sqrt(s["vel"] / n).float(), prog_bar=stage == "val")

    def validation_step(self, batch, batch_idx):
        self._eval_step(batch, "val")

    def on_validation_epoch_end(self):
        self._eval_epoch_end("val")

    def test_step(self, batch, batch_idx):
        self._eval_step(batch, "test")

    def on_test_epoch_end(self):
        self._eval_epoch_end("test")

    def configure_optimizers(self):
        o = self.optim_cfg
        opt = torch.optim.Adam(self.parameters(), lr=o.lr, weight_decay=o.weight_decay)
        if o.schedule == "cosine":
            sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(1, self.max_epochs), eta_min=o.lr * o.min_lr_ratio)
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}
        if o.schedule == "plateau":
            sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.2, patience=o.plateau_patience)
            return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": "val/pos_rmse_m"}}
        return opt

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["pmsr"] = self.meta
