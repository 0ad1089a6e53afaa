"""Training data for trackers that read detections, drawn on the fly: scenes of several targets
(:func:`pmsr_nn.simulation.scenes.draw_scenes`) and their detections, with a Pd and a clutter
count drawn per batch, for NEBP (:mod:`.nebp_training`). (The end-to-end set tracker and the hybrid,
removed under issue 56, drew their scenes here too; they are at commits 4699b3d and c270857.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..config import check_interval, require
from ..errors import ConfigError


@dataclass(frozen=True)
class SceneConfig:
    """What the training scenes are (:func:`~pmsr_nn.simulation.scenes.draw_scenes`): ``window`` scans,
    ``targets`` (fewest, most) per scene, the chances of a formation mate and a crossing target,
    ``pd`` and ``clutter_per_scan`` ranges (per batch; clutter per pair and scan, uniform over the
    box below), and the detections' noise deviations. ``births``: the chance that a target other
    than target 0 is born at a uniform scan of the window's first half, absent (NaN, undetected)
    before it; 0 (the default) keeps every target alive throughout, and the draws as they were."""

    window: int = 60
    targets: tuple[int, int] = (2, 4)
    formation: float = 0.35
    crossing: float = 0.35
    pd: tuple[float, float] = (0.7, 0.95)
    clutter_per_scan: tuple[int, int] = (10, 50)
    range_m: tuple[float, float] = (0.0, 25000.0)
    range_rate_mps: tuple[float, float] = (-40.0, 40.0)
    noise: dict = field(default_factory=lambda: {"range_m": 30.0, "range_rate_mps": 2.0, "azimuth_deg": 3.0})
    births: float = 0.0

    def __post_init__(self) -> None:
        require(self.window >= 5, f"scenes.window must be at least 5 scans, got {self.window}")
        require(0.0 <= self.births <= 1.0, f"scenes.births must be a chance in [0, 1], got {self.births}")
        require(1 <= self.targets[0] <= self.targets[1] <= 20, f"scenes.targets must be 1 <= fewest <= most <= 20, "
                                                                f"got {self.targets}")
        require(0.0 < self.pd[0] <= self.pd[1] <= 1.0, f"scenes.pd must lie in (0, 1], got {self.pd}")
        require(0 <= self.clutter_per_scan[0] <= self.clutter_per_scan[1], "scenes.clutter_per_scan must be "
                                                                             "0 <= fewest <= most")
        check_interval("scenes.range_m", self.range_m, nonneg=True)
        check_interval("scenes.range_rate_mps", self.range_rate_mps)
        require(set(self.noise) == {"range_m", "range_rate_mps", "azimuth_deg"} and all(
            isinstance(v, (int, float)) and v > 0 for v in self.noise.values()),
            "scenes.noise needs positive range_m, range_rate_mps and azimuth_deg")


@dataclass(frozen=True)
class FlyOptimConfig:
    """Optimisation of a tracker trained on scenes drawn on the fly: ``steps`` Adam steps of
    ``batch_size`` scenes, validation every ``val_every`` steps on ``val_scenes`` fixed scenes,
    gradient clipping, an optional time limit."""

    lr: float = 1.0e-3
    batch_size: int = 16
    steps: int = 300
    val_every: int = 50
    val_scenes: int = 32
    gradient_clip_val: float = 1.0
    max_time_minutes: float | None = None

    def __post_init__(self) -> None:
        require(self.lr > 0 and self.batch_size >= 1 and self.steps >= 1 and self.val_every >= 1
                and self.val_scenes >= 1, "optim: lr, batch_size, steps, val_every and val_scenes must be positive")
        require(self.max_time_minutes is None or self.max_time_minutes > 0, "optim: max_time_minutes must be positive")

    @property
    def val_batches(self) -> int:
        return max(1, math.ceil(self.val_scenes / self.batch_size))


def resolve_recipe_path(recipe: str, config_path) -> str:
    """A config's ``recipe``, relative to the config file; one-line error if it is not there."""
    path = Path(recipe)
    if not path.is_absolute():
        path = Path(config_path).parent / path
    if not path.is_file():
        raise ConfigError(f"train config: recipe {recipe} not found (looked at {path})")
    return str(path)


class SceneSampler:
    """Scenes of a recipe (its geometry, motion and interval) seen by detections of range,
    range-rate and azimuth with the deviations of ``scenes.noise``."""

    def __init__(self, recipe_path: str, scenes: SceneConfig):
        from ..measurements import MeasurementModel
        from ..simulation.recipe import load_recipe
        from ..simulation.tracks import build_models

        self.scenes = scenes
        self.recipe = load_recipe(recipe_path)
        self.motion, stream = build_models(self.recipe)
        n = scenes.noise
        self.noise_std = (n["range_m"], n["range_rate_mps"], math.radians(n["azimuth_deg"]))
        self.model = MeasurementModel(stream.geometry, ("range", "range_rate", "azimuth"), self.noise_std,
                                      self.motion.pos_idx, self.motion.vel_idx, layout="pair")
        self.dt = self.recipe.motion.dt_s

    def draw(self, seed: tuple[int, ...], B: int):
        """``(scans, truth (B, K, N, n), pd, clutter, generator)`` of ``B`` scenes from ``seed`` (the
        generator goes on with the draws a caller adds)."""
        from ..rng import seeded_generator
        from ..simulation.detections import ClutterSpec, simulate_scans
        from ..simulation.scenes import draw_scenes

        s = self.scenes
        g = seeded_generator(*seed)
        N = int(torch.randint(s.targets[0], s.targets[1] + 1, (1,), generator=g))
        pd = s.pd[0] + (s.pd[1] - s.pd[0]) * float(torch.rand(1, generator=g, dtype=torch.float64))
        per_scan = int(torch.randint(s.clutter_per_scan[0], s.clutter_per_scan[1] + 1, (1,), generator=g))
        truth = draw_scenes(self.recipe, self.model.geometry, B, N, s.window, g, s.formation, s.crossing)
        clutter = ClutterSpec(per_scan=per_scan, range_m=s.range_m, range_rate_mps=s.range_rate_mps)
        alive = None
        if s.births > 0:  # drawn only then: a config without births draws the scenes it always drew
            K = s.window
            late = torch.rand(B, N, generator=g, dtype=torch.float64) < s.births
            late[:, 0] = False
            birth = torch.where(late, torch.randint(1, K // 2 + 1, (B, N), generator=g), 0)  # (B, N)
            alive = torch.arange(K)[None, :, None] >= birth[:, None, :]  # (B, K, N)
            truth = torch.where(alive[..., None], truth, torch.full((), math.nan, dtype=truth.dtype))
        return simulate_scans(truth, self.model, pd, clutter, g, alive=alive), truth, pd, clutter, g


def start_run(out: Path, cfg, recipe: str) -> None:
    """Check that ``out`` is a new run folder (nothing is written before), then create and mark it
    and write the resolved ``cfg`` to ``config.yaml``."""
    import yaml

    from ..config import to_dict
    from ..outputs import write_marker
    from .training import check_run_folder

    check_run_folder(out, resume=False, inputs=[Path(recipe)])
    out.mkdir(parents=True, exist_ok=True)
    write_marker(out, "train", state="running")
    (out / "config.yaml").write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))


def mean_figures(rows: list[dict]) -> dict:
    """The mean of each figure over validation batches ``rows`` (as Lightning logs a trained network's)."""
    return {k: sum(float(r[k]) for r in rows) / len(rows) for k in rows[0]}


def finish_run(out: Path, trainer, ckpt, seconds: float, baseline: dict, monitor: str) -> dict:
    """Write a run folder's ``metrics.json`` (steps, fit seconds, the model-based tracker's
    validation figures ``baseline``, the monitored figure and its best, the last logged figures,
    threads) and mark the run done; returns the metrics."""
    import json

    from ..outputs import write_marker

    metrics = {"steps": int(trainer.global_step), "fit_seconds": seconds, "baseline_val": baseline, "monitor": monitor,
               "best_val": float(ckpt.best_model_score) if ckpt.best_model_score is not None else None,
               "last": {k: float(v) for k, v in trainer.callback_metrics.items()}, "threads": torch.get_num_threads()}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    write_marker(out, "train", state="done")
    return metrics


def fit_on_the_fly(module, out: Path, steps: int, val_every: int, val_batches: int, clip: float,
                   max_time_minutes: float | None, accelerator: str = "cpu", monitor: str = "val/loss",
                   progress: bool = False):
    """Fit a Lightning ``module`` whose ``training_step(i)`` draws batch ``i`` itself (step indices
    in, no dataset) and whose ``validation_step(j)`` reads fixed batch ``j``: TensorBoard in
    ``out/tb``, the best (lowest ``monitor``) and last checkpoints in ``out/checkpoints``; the best
    weights are loaded back into ``module``; ``progress``: a line per validation
    (:class:`~.progress.StepProgress`). Returns ``(trainer, checkpoint callback, fit seconds)``."""
    import time

    import lightning.pytorch as pl
    from lightning.pytorch.callbacks import ModelCheckpoint
    from lightning.pytorch.loggers import TensorBoardLogger

    from .progress import StepProgress, quiet_lightning

    # after every validation, also where val_every is 1 (Lightning reads a check interval of 1 as "once an epoch" and
    # would otherwise keep only the epoch's end: the best step lost)
    ckpt = ModelCheckpoint(dirpath=out / "checkpoints", filename="best", monitor=monitor, mode="min", save_last=True,
                           save_on_train_epoch_end=False)
    with quiet_lightning(True):
        trainer = pl.Trainer(max_steps=steps, max_epochs=1, val_check_interval=min(val_every, steps),
                             accelerator=accelerator, devices=1, logger=TensorBoardLogger(out, name="tb", version=""),
                             callbacks=[ckpt, *([StepProgress(steps, max_time_minutes, monitor)] if progress else [])],
                             gradient_clip_val=clip, enable_progress_bar=False,
                             enable_model_summary=False, num_sanity_val_steps=0,
                             max_time=None if max_time_minutes is None else {"minutes": max_time_minutes})
        t0 = time.perf_counter()
        trainer.fit(module, torch.utils.data.DataLoader(list(range(steps)), batch_size=None),
                    torch.utils.data.DataLoader(list(range(val_batches)), batch_size=None))
    seconds = time.perf_counter() - t0
    if ckpt.best_model_path:
        module.load_state_dict(torch.load(ckpt.best_model_path, map_location="cpu", weights_only=True)["state_dict"])
    return trainer, ckpt, seconds
