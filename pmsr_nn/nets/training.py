"""``pmsr train``: one training run from a YAML config (:mod:`.train_config`) into a
self-describing run folder.

Run folder::

    RUN/config.yaml          the resolved config (every default spelled out)
    RUN/checkpoints/best.ckpt   Lightning checkpoint with the lowest validation position RMSE
    RUN/checkpoints/last.ckpt   the latest state, rewritten every ``checkpoint_every_n_steps``
    RUN/tb/                  TensorBoard logs (``tensorboard --logdir RUN/tb``)
    RUN/tracker.pt           the best weights as a slim, self-contained inference checkpoint
    RUN/metrics.json         final validation and test metrics, validation history, throughput

An interrupted run continues with ``--resume`` (same config) from ``last.ckpt``, or, where that
is missing or unreadable (deleted, moved, truncated), from the newest readable other checkpoint
in ``checkpoints/`` (``best.ckpt``); one line on stderr says which (:func:`resume_point`). A run
with a result (a checkpoint file, ``tracker.pt`` or ``metrics.json``) but no readable checkpoint
is refused: starting it afresh would replace that result. A resumed session never replaces a
better best with a worse one: the validation position RMSE that ``metrics.json`` records for the
kept best is the bar a new ``best.ckpt`` must beat, and a session whose best is worse keeps the
earlier ``tracker.pt`` and the earlier metrics (the validation history of both sessions merged).
Every Lightning checkpoint carries the ``pmsr`` block, so any of them serves ``pmsr track``.

Nothing is written before the whole config, the data, the window and the accelerator have been
checked, so a refused run leaves no folder behind. The folder carries our output marker; a run
that fails or is interrupted before its first checkpoint is removed again (nothing in it could be
resumed), one that has a checkpoint is kept for ``--resume``. A run killed outright before its
first checkpoint leaves a marked folder holding only its config (no checkpoint, tracker.pt or
metrics.json): ``--resume`` starts it afresh. tracker.pt and metrics.json are replaced atomically,
so a failed write (a full disk) leaves the earlier ones whole. Every checkpoint is read with
``weights_only=True``, Lightning's resume included.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import yaml
from lightning.fabric.plugins import TorchCheckpointIO
from lightning.pytorch.callbacks import Callback, ModelCheckpoint

from .. import interrupts
from ..config import from_dict, load_yaml, to_dict
from ..errors import ConfigError
from ..outputs import write_marker
from .checkpoint import save_atomically, save_tracker, tracker_metadata, write_atomically
from .train_config import DataConfig, TrainConfig, TrainerConfig, resolve_recipe

_CHILD_ENV = "PMSR_TRAIN_RUN"  # set before fit: DDP worker processes re-run the command and must not refuse the folder


def native_bf16(accelerator: str) -> bool:
    """Whether bfloat16 matrix products run natively here: a CUDA GPU that has them, or a CPU with
    AVX512-BF16 / AMX (oneDNN's check). Without them CPU bfloat16 is emulated, ~10-30x slower."""
    import torch

    if accelerator in ("auto", "gpu", "cuda") and torch.cuda.is_available():
        return torch.cuda.is_bf16_supported()
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a build without oneDNN: assume emulation
        return False


def resolve_precision(precision: str, accelerator: str = "auto") -> str:
    """``auto``: ``bf16-mixed`` where :func:`native_bf16`, else ``32-true``; anything else as given."""
    if precision != "auto":
        return precision
    return "bf16-mixed" if native_bf16(accelerator) else "32-true"


def prepare_dataset(data: DataConfig, progress: bool = True) -> Path:
    """The dataset directory for ``data``: the given path, or the recipe simulated into the cache."""
    from ..data.store import is_our_dataset, open_dataset, write_dataset

    if data.path is not None:
        open_dataset(data.path).close()  # clear error now if it is not one of ours
        return Path(data.path)
    recipe = resolve_recipe(data)
    key = hashlib.sha256(json.dumps(recipe.to_dict(), sort_keys=True).encode()).hexdigest()[:10]
    out = Path(data.cache_dir) / f"{recipe.name}-{recipe.variant}-{recipe.tracks}x{recipe.motion.steps}-{key}"
    if not is_our_dataset(out):
        # creates cache_dir (and removes it again on failure)
        write_dataset(recipe, out, progress=progress, what=f"data.cache_dir {data.cache_dir}: dataset")
    return out


# -- the run folder --------------------------------------------------------------------------

def check_run_folder(out: Path, resume: bool, inputs=()) -> None:
    """Refuse (one line) a training output folder ``out`` that is never safe to write
    (:func:`~pmsr_nn.outputs.check_target`: the working directory, one of the ``inputs``, ...);
    with ``resume``, one that is not a readable training run."""
    from ..outputs import check_target, output_kind

    if os.environ.get(_CHILD_ENV) == str(out.resolve()):
        return
    check_target(out, inputs=inputs)
    if resume:
        if not (out / "config.yaml").is_file():
            raise ConfigError(f"cannot resume: {out} is not a pmsr training run (no config.yaml)")
        if output_kind(out) not in (None, "train"):
            raise ConfigError(f"cannot resume: {out} holds the output of 'pmsr {output_kind(out)}', not a training run")
        resume_point(out)  # no readable checkpoint in a run with a result: refused here, before anything is written
        return
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise ConfigError(f"--out {out} exists and is not a folder; give a new run folder")
    if out.exists() and any(out.iterdir()):
        if output_kind(out) == "train" or (out / "config.yaml").is_file():
            raise ConfigError(f"--out {out} holds a training run: pass --resume to continue it, or choose another --out")
        raise ConfigError(f"--out {out} exists and holds files that are not a training run; pmsr never writes into "
                          "them: choose a new or empty folder")


def resume_point(out: Path) -> tuple[Path | None, str]:
    """Where ``--resume`` continues the run ``out``: ``(checkpoint or None, one line saying which)``.

    ``checkpoints/last.ckpt``; where it is missing or unreadable (empty, truncated, foreign, pickled),
    the newest (by modification time) readable other ``checkpoints/*.ckpt``. None (start afresh) only
    for a run that never wrote a result: no checkpoint file, tracker.pt or metrics.json. Refused
    (ConfigError): a folder at last.ckpt (the run could not write its checkpoint there), and a run
    with a result but no readable checkpoint (starting afresh would replace the result)."""
    from ..errors import CheckpointError
    from .checkpoint import read_checkpoint

    ckpt_dir = out / "checkpoints"
    last = ckpt_dir / "last.ckpt"
    if last.is_dir():
        raise ConfigError(f"cannot resume: {last} is a folder, where the run writes its checkpoint; move it away")
    others = sorted((p for p in ckpt_dir.glob("*.ckpt") if p != last and p.is_file()),
                    key=lambda p: p.stat().st_mtime, reverse=True) if ckpt_dir.is_dir() else []
    why = None
    for path in [last, *others]:
        try:
            read_checkpoint(path)  # truncated, foreign or pickled: passed over here, before Lightning sees it
        except CheckpointError as exc:
            why = why or str(exc)
            continue
        return path, f"resuming from {path}" + (f" ({why})" if path != last else "")
    results = [p.name for p in (*([last] if last.exists() else []), *others, out / "tracker.pt", out / "metrics.json")
               if p.exists()]
    if results:
        raise ConfigError(f"cannot resume {out}: no readable checkpoint in {ckpt_dir} ({why}); starting afresh would "
                          f"replace its {', '.join(results)}: train into a new --out")
    return None, f"resuming {out}: it has no checkpoint yet (stopped before its first), so training starts afresh"


def recorded_best(out: Path) -> dict | None:
    """The metrics of the kept best of an earlier session (``metrics.json``), or None where there is
    none readable or its validation position RMSE is not finite (a diverged run sets no bar): a dict
    with ``val`` and ``test`` (``pos_rmse_m`` in m, ...) and ``best_checkpoint``."""
    import math

    try:
        old = json.loads((out / "metrics.json").read_text())
        finite = math.isfinite(float(old["val"]["pos_rmse_m"]))
        old["test"], old["best_checkpoint"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return old if finite else None


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning's checkpoint writer, atomic on any file system (:func:`~.checkpoint.save_atomically`;
    Lightning's own writes a temporary file in the system's temporary folder and copies it over
    the checkpoint, which a full disk leaves half-written): a failed write keeps the earlier checkpoint."""

    def save_checkpoint(self, checkpoint: dict, path, storage_options=None) -> None:
        if storage_options is not None:
            raise TypeError("storage_options are not supported")
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        save_atomically(checkpoint, path)


class BestCheckpoint(ModelCheckpoint):
    """Lightning's best-checkpoint callback with a bar: a validation score no better than
    ``bar`` (the recorded best's, m) never replaces ``best.ckpt``, whatever state was restored."""

    def __init__(self, *args, bar: float | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.bar = bar

    @property
    def state_key(self) -> str:  # ModelCheckpoint's: the state in a checkpoint written by either restores into both
        return super().state_key.replace(type(self).__qualname__, ModelCheckpoint.__qualname__, 1)

    def check_monitor_top_k(self, trainer, current=None) -> bool:
        if self.bar is not None and current is not None and not float(current) < self.bar:
            return False
        return super().check_monitor_top_k(trainer, current)


def _check_accelerator(tc: "TrainerConfig") -> None:
    import torch

    acc = tc.accelerator.lower()
    if acc in ("gpu", "cuda") and not torch.cuda.is_available():
        raise ConfigError(f"trainer.accelerator={tc.accelerator}: no CUDA GPU is available on this machine "
                          "(use auto or cpu)")
    if acc == "mps" and not torch.backends.mps.is_available():
        raise ConfigError("trainer.accelerator=mps: no Apple GPU is available on this machine (use auto or cpu)")
    if acc not in ("auto", "cpu", "gpu", "cuda", "mps", "tpu"):
        raise ConfigError(f"trainer.accelerator: unknown accelerator {tc.accelerator!r} (auto, cpu, gpu, cuda, mps)")


def train(cfg: TrainConfig | None, out: str | Path, *, resume: bool = False, console: str = "lines",
          label: str = "training") -> dict:
    """Train ``cfg`` into the run folder ``out``; return the final metrics (also in metrics.json).

    With ``resume``, ``cfg`` may be None (the run's own config.yaml is used); a given config must
    equal it. ``console``: what the run prints (:mod:`pmsr_nn.nets.progress`; ``trainer.progress:
    false`` silences it), ``label`` the progress bar's.
    """
    from .progress import CONSOLES, quiet_lightning
    from .torch_settings import restored_torch_settings

    if console not in CONSOLES:
        raise ValueError(f"console must be one of {CONSOLES}, got {console!r}")
    with quiet_lightning(console != "lightning"), restored_torch_settings():  # _train sets the config's threads
        return _train(cfg, Path(out), resume, console, label)


def _train(cfg: TrainConfig | None, out: Path, resume: bool, console: str, label: str) -> dict:
    import lightning as L
    import torch
    from lightning.pytorch.callbacks import EarlyStopping, LearningRateMonitor
    from lightning.pytorch.loggers import TensorBoardLogger

    from ..data.datamodule import TrackWindowDataModule
    from .module import TrackerModule
    from .progress import EpochProgress
    from .representation import fit_on_training_tracks

    check_run_folder(out, resume, inputs=[p for p in (cfg and cfg.data.path, cfg and cfg.data.recipe) if p])
    if resume:
        stored = from_dict(TrainConfig, load_yaml(out / "config.yaml"), where=f"{out}/config.yaml")
        if cfg is not None and to_dict(cfg) != to_dict(stored):
            raise ConfigError(f"the given config differs from {out}/config.yaml; resume with the run's own config (omit CONFIG)")
        cfg = stored
    tc = cfg.trainer
    console = console if tc.progress else "none"
    _check_accelerator(tc)
    if tc.threads:
        torch.set_num_threads(tc.threads)
    dataset = prepare_dataset(cfg.data, progress=console != "none")
    dm = TrackWindowDataModule(dataset, window=cfg.data.window, batch_size=cfg.data.batch_size,
                               num_workers=cfg.data.num_workers, seed=cfg.seed,
                               fold=cfg.data.fold, folds=cfg.data.folds,
                               eval_window_stride=cfg.data.eval_window_stride,
                               representation=functools.partial(fit_on_training_tracks, cfg.model))
    for split in ("train", "val", "test"):  # a window longer than the tracks, an empty split: refused now
        if len(dm.dataset(split)) == 0:
            raise ConfigError(f"the {split} split of {dataset} holds no windows of {dm.window} samples; "
                              "simulate more tracks or shorten data.window")
    meta = tracker_metadata(cfg.model, dm.manifest, dm.normalisation(), window=dm.window, seed=cfg.seed,
                            fold=cfg.data.fold, folds=cfg.data.folds, run=cfg.name)
    L.seed_everything(cfg.seed, workers=True, verbose=False)
    module = TrackerModule(to_dict(cfg.model), to_dict(cfg.optim), meta, max_epochs=tc.max_epochs)
    behind, ahead = module.net.context
    if behind is not None and behind + ahead + 1 > dm.window:
        raise ConfigError(f"model: each estimate reads {behind + ahead + 1} samples (filter_order and layers), more "
                          f"than the window of {dm.window}; shorten model.filter_order or lengthen data.window")
    with torch.no_grad(), torch.random.fork_rng():  # a model that cannot run this window fails now, not in fit
        module.net(torch.zeros(1, dm.window, cfg.model.input_dim(meta["dim_z"], meta["dim_x"]),
                               dtype=next(module.net.parameters()).dtype))

    ckpt_dir = out / "checkpoints"
    start, said = resume_point(out) if resume else (None, "")
    before = recorded_best(out) if resume else None
    best = BestCheckpoint(dirpath=ckpt_dir, filename="best", monitor="val/pos_rmse_m", mode="min",
                          save_top_k=1, auto_insert_metric_name=False, enable_version_counter=False,
                          bar=before and float(before["val"]["pos_rmse_m"]))
    last = ModelCheckpoint(dirpath=ckpt_dir, filename="last", save_top_k=0, save_last=True,
                           every_n_train_steps=tc.checkpoint_every_n_steps,
                           enable_version_counter=False)  # a run moved to another folder rewrites its last.ckpt
    history = ValidationHistory()
    callbacks = [best, last, history, LearningRateMonitor(logging_interval="epoch")]
    if console in ("lines", "bar"):
        callbacks.append(EpochProgress(console, tc.max_epochs, tc.max_time_minutes, label=label))
    if tc.early_stopping_patience:
        callbacks.append(EarlyStopping(monitor="val/pos_rmse_m", mode="min", patience=tc.early_stopping_patience))
    from lightning.fabric.utilities.exceptions import MisconfigurationException

    try:
        trainer = L.Trainer(
            default_root_dir=out, max_epochs=tc.max_epochs,
            max_time={"minutes": tc.max_time_minutes} if tc.max_time_minutes else None,
            limit_train_batches=tc.train_batches_per_epoch or 1.0, limit_val_batches=tc.val_batches or 1.0,
            accelerator=tc.accelerator, devices=tc.devices, strategy=tc.strategy, num_nodes=tc.num_nodes,
            precision=resolve_precision(tc.precision, tc.accelerator), deterministic=tc.deterministic, gradient_clip_val=tc.gradient_clip_val,
            logger=TensorBoardLogger(save_dir=out, name="tb", version="", default_hp_metric=False),
            callbacks=callbacks, log_every_n_steps=tc.log_every_n_steps, plugins=[AtomicCheckpointIO()],
            enable_progress_bar=console == "lightning", enable_model_summary=console == "lightning",
        )
    except (MisconfigurationException, ValueError, RuntimeError) as exc:
        raise ConfigError(f"trainer: {' '.join(str(exc).split())[:300]}") from None

    # Everything is checked: only now is the run folder written.
    created = _start_run_folder(out, cfg, write=trainer.is_global_zero and not resume)
    resumed_from = str(start) if start is not None else None
    if said and trainer.is_global_zero:
        print(f"pmsr: {said}", file=sys.stderr)
    os.environ[_CHILD_ENV] = str(out.resolve())
    t0 = time.perf_counter()
    try:
        trainer.fit(module, datamodule=dm, ckpt_path=resumed_from, weights_only=True)
    except BaseException as exc:
        _after_failed_fit(out, created, exc)
        raise
    finally:
        os.environ.pop(_CHILD_ENV, None)  # workers have inherited it; this process must check again next time
    fit_seconds = time.perf_counter() - t0

    # best.ckpt by its fixed name (a restored best_model_path names the folder the run was in when saved)
    best_path = str(ckpt_dir / "best.ckpt") if (ckpt_dir / "best.ckpt").is_file() else str(ckpt_dir / "last.ckpt")
    val = trainer.validate(module, datamodule=dm, ckpt_path=best_path, verbose=False, weights_only=True)
    test = trainer.test(module, datamodule=dm, ckpt_path=best_path, verbose=False, weights_only=True)
    metrics = {
        "run": cfg.name,
        "dataset": str(dataset),
        "best_checkpoint": os.path.relpath(best_path, out),  # relative: the run folder may be moved
        "resumed_from": resumed_from,
        "epochs": trainer.current_epoch,
        "global_step": trainer.global_step,
        "fit_seconds_this_session": round(fit_seconds, 3),
        "train_windows_per_second": history.windows_per_second(),
        "val": {k.split("/", 1)[1]: float(v) for k, v in val[0].items()},
        "test": {k.split("/", 1)[1]: float(v) for k, v in test[0].items()},
        "history": history.records,
        "context_samples": {"behind": module.net.context[0], "ahead": module.net.context[1]},
        "looks_ahead": cfg.model.looks_ahead,
        "parameters": sum(p.numel() for p in module.net.parameters()),
        "world_size": trainer.world_size,
        "global_rank": trainer.global_rank,
    }
    keep = before is not None and not metrics["val"]["pos_rmse_m"] <= before["val"]["pos_rmse_m"]
    if keep:  # this session's best is worse than the recorded one: the earlier tracker.pt and its metrics stay
        metrics.update(val=before["val"], test=before["test"], best_checkpoint=before["best_checkpoint"])
    if trainer.is_global_zero:
        if not keep:
            save_tracker(out / "tracker.pt", meta, {f"net.{k}": v for k, v in module.net.state_dict().items()})
        _merge_history(out / "metrics.json", metrics)
        write_atomically(out / "metrics.json", (json.dumps(metrics, indent=2) + "\n").encode(), "metrics")
        write_marker(out, "train", state="finished")
    return metrics


def _start_run_folder(out: Path, cfg: TrainConfig, write: bool) -> list[Path]:
    """Create and mark the run folder (rank 0 of a new run); the folders this call created
    (parents first, the run folder last), none when it existed."""
    if not write:
        return []
    from ..outputs import make_parents

    made = make_parents(out)
    if not out.exists():
        made.append(out)
    out.mkdir(exist_ok=True)
    write_marker(out, "train", state="running")
    (out / "config.yaml").write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))
    return made


def _after_failed_fit(out: Path, created: list[Path], exc: BaseException) -> None:
    """A new run that stopped before its first checkpoint is removed (only the folders this call
    created, and only while the run folder carries our train marker); one with a checkpoint is kept."""
    import shutil

    from ..errors import Interrupted
    from ..outputs import output_kind, remove_if_empty

    if (out / "checkpoints" / "last.ckpt").is_file() or (out / "checkpoints" / "best.ckpt").is_file():
        if isinstance(exc, (Interrupted, KeyboardInterrupt)):
            exc.kept = f"the run is kept at {out}: continue it with 'pmsr train --resume --out {out}'"
        return
    if created and created[-1] == out and output_kind(out) == "train":
        shutil.rmtree(out, ignore_errors=True)
        remove_if_empty(created[:-1])


def _merge_history(path: Path, metrics: dict) -> None:
    """A resumed run keeps the validation history of the sessions before it."""
    if path.is_file():
        try:
            old = json.loads(path.read_text()).get("history", [])
        except ValueError:
            old = []
        seen = {(r["epoch"], r["step"]) for r in metrics["history"]}
        metrics["history"] = [r for r in old if (r["epoch"], r["step"]) not in seen] + metrics["history"]


class ValidationHistory(Callback):
    """Validation position RMSE against wall time, and training throughput (windows/s)."""

    def __init__(self):
        self.records: list[dict[str, Any]] = []
        self._t0 = None
        self._windows = 0
        self._train_seconds = 0.0
        self._batch_t = None

    def on_train_start(self, trainer, pl_module):
        self._t0 = time.perf_counter()

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        self._batch_t = time.perf_counter()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        interrupts.check()  # a signal whose exception a weakref callback swallowed still stops the run
        if self._batch_t is not None:
            self._train_seconds += time.perf_counter() - self._batch_t
            self._windows += len(batch[0]) * trainer.world_size

    def on_validation_end(self, trainer, pl_module):
        # Not on_validation_epoch_end: callbacks run that hook before the module logs the epoch's
        # metrics, so they would read the previous epoch's (every record one epoch late).
        m = trainer.callback_metrics
        if trainer.sanity_checking or trainer.state.fn != "fit" or "val/pos_rmse_m" not in m:
            return
        self.records.append({
            "epoch": trainer.current_epoch, "step": trainer.global_step,
            "wall_seconds": round(time.perf_counter() - (self._t0 or time.perf_counter()), 3),
            "val_pos_rmse_m": float(m["val/pos_rmse_m"]), "val_vel_rmse_mps": float(m.get("val/vel_rmse_mps", float("nan"))),
        })

    def windows_per_second(self) -> float | None:
        return round(self._windows / self._train_seconds, 1) if self._train_seconds > 0 else None
