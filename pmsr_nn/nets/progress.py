"""What a training run prints: one line per epoch, or one progress bar, instead of Lightning's bars.

``console`` of :func:`pmsr_nn.nets.training.train`:

``"lines"`` (``pmsr train``)
    one line per validated epoch: the last batch's training loss, validation RMSE, the epoch's time and an
    estimate of the time left (mean epoch time so far x epochs left, capped by
    ``trainer.max_time_minutes``);
``"bar"`` (``pmsr demo``)
    a single bar over every training batch of the run, with the last validation RMSE and
    tqdm's time left; it clears itself when the run ends (the caller prints the summary);
``"lightning"`` (``--verbose``)
    Lightning's own progress bars, model summary and start-up messages;
``"none"``
    nothing (``trainer.progress: false``).
"""

from __future__ import annotations

import logging
import sys
import time
import warnings
from contextlib import contextmanager

from lightning.pytorch.callbacks import Callback

CONSOLES = ("lines", "bar", "lightning", "none")


_LIGHTNING_LOGGERS = ("lightning.pytorch", "lightning.fabric", "pytorch_lightning")
_HARMLESS = (".*does not have many workers.*", ".*LeafSpec.*", ".*number of training batches.*")
"""Lightning warnings that say nothing about a run of ours: one data-loader process is our
default on purpose; LeafSpec is a deprecation inside Lightning; small smoke datasets have fewer
batches than the logging interval."""


@contextmanager
def quiet_lightning(enabled: bool = True):
    """Lightning's start-up messages ("GPU available", tips) and :data:`_HARMLESS` warnings kept out
    of the console while the block runs; the loggers' levels are restored after it."""
    if not enabled:
        yield
        return
    levels = {name: logging.getLogger(name).level for name in _LIGHTNING_LOGGERS}
    try:
        for name in _LIGHTNING_LOGGERS:
            logging.getLogger(name).setLevel(logging.WARNING)
        with warnings.catch_warnings():
            for message in _HARMLESS:
                warnings.filterwarnings("ignore", message=message)
            yield
    finally:
        for name, level in levels.items():
            logging.getLogger(name).setLevel(level)


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"


class EpochProgress(Callback):
    """The ``"lines"`` and ``"bar"`` consoles (module docstring); rank 0 only."""

    def __init__(self, style: str, max_epochs: int, max_time_minutes: float | None = None, label: str = "training",
                 stream=None):
        if style not in ("lines", "bar"):
            raise ValueError(f"unknown progress style {style!r}")
        self.style, self.max_epochs, self.label = style, max_epochs, label
        self.max_seconds = None if max_time_minutes is None else 60.0 * max_time_minutes
        self.stream = stream or sys.stderr  # the lines go to stdout (print); a bar to stderr
        self._bar = None
        self._t_start = self._t_epoch = None
        self._first_epoch = 0

    def on_train_start(self, trainer, pl_module):
        if not trainer.is_global_zero:
            return
        self._t_start = time.perf_counter()
        self._first_epoch = trainer.current_epoch
        if self.style == "bar":
            from tqdm.auto import tqdm

            per_epoch = int(trainer.num_training_batches) if trainer.num_training_batches != float("inf") else None
            total = None if per_epoch is None else per_epoch * (self.max_epochs - trainer.current_epoch)
            self._bar = tqdm(total=total, unit="batch", desc=self.label, leave=False, file=self.stream,
                             dynamic_ncols=True)

    def on_train_epoch_start(self, trainer, pl_module):
        self._t_epoch = time.perf_counter()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        if self._bar is not None:
            self._bar.update(1)

    def on_validation_end(self, trainer, pl_module):  # after the module has logged the epoch's metrics
        m = trainer.callback_metrics
        if (trainer.sanity_checking or trainer.state.fn != "fit" or not trainer.is_global_zero
                or "val/pos_rmse_m" not in m):
            return
        val = f"val position RMSE {float(m['val/pos_rmse_m']):.1f} m"
        if self._bar is not None:
            self._bar.set_postfix_str(val, refresh=False)
            return
        now = time.perf_counter()
        done = trainer.current_epoch + 1 - self._first_epoch
        mean = (now - self._t_start) / max(done, 1)
        left = mean * max(self.max_epochs - trainer.current_epoch - 1, 0)
        if self.max_seconds is not None:
            left = min(left, max(self.max_seconds - (now - self._t_start), 0.0))
        loss = m.get("train/loss")
        vel = m.get("val/vel_rmse_mps")
        width = len(str(self.max_epochs))
        print(f"epoch {trainer.current_epoch + 1:>{width}}/{self.max_epochs}"
              + (f"   last batch loss {float(loss):.4g}" if loss is not None else "")
              + f"   {val}" + (f", velocity {float(vel):.2f} m/s" if vel is not None else "")
              + f"   {now - (self._t_epoch or now):.1f} s"
              + (f"   ~{_duration(left)} left" if left > 0 else ""), flush=True)

    def teardown(self, trainer, pl_module, stage):
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class StepProgress(Callback):
    """One line per validation of a run trained by steps on scenes drawn on the fly
    (:func:`~pmsr_nn.nets.scene_data.fit_on_the_fly`): the step, the validation loss and the best
    so far, the validation figures the module logs (position RMSE, GOSPA), the time since the
    start and an estimate of the time left (mean step time x steps left, capped by
    ``max_time_minutes``); rank 0 only."""

    FIGURES = (("val/pos_rmse_m", "position RMSE {:.1f} m"), ("val/gospa_m", "GOSPA {:.1f} m"))

    def __init__(self, steps: int, max_time_minutes: float | None = None, monitor: str = "val/loss"):
        self.steps, self.monitor = steps, monitor
        self.max_seconds = None if max_time_minutes is None else 60.0 * max_time_minutes
        self.best = None
        self._t_start = None

    def on_train_start(self, trainer, pl_module):
        self._t_start = time.perf_counter()

    def on_validation_end(self, trainer, pl_module):
        m = trainer.callback_metrics
        if trainer.sanity_checking or not trainer.is_global_zero or self.monitor not in m or self._t_start is None:
            return
        loss = float(m[self.monitor])
        self.best = loss if self.best is None else min(self.best, loss)
        step = int(trainer.global_step)
        elapsed = time.perf_counter() - self._t_start
        left = elapsed / max(step, 1) * max(self.steps - step, 0)
        if self.max_seconds is not None:
            left = min(left, max(self.max_seconds - elapsed, 0.0))
        figures = [fmt.format(float(m[key])) for key, fmt in self.FIGURES if key in m]
        print(f"step {step:>{len(str(self.steps))}}/{self.steps}   validation loss {loss:.4g} (best {self.best:.4g})"
              + "".join(f"   {f}" for f in figures) + f"   {_duration(elapsed)}"
              + (f"   ~{_duration(left)} left" if left > 0 else ""), flush=True)

