"""The ``LightningDataModule`` serving normalised (measurement window, state window) pairs."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Subset

from ..errors import ConfigError
from .normalise import MinMaxScaler, RunningMinMax
from .store import open_dataset
from .windows import WindowDataset


class EpochShuffler(torch.utils.data.Sampler):
    """Training order: the shuffle of torch's ``RandomSampler`` with a generator seeded once by
    ``seed`` (so results equal those of earlier releases), recomputed from ``(seed, epoch)`` so
    that a run resumed mid-epoch continues with exactly the windows the interrupted run would
    have drawn.

    Per epoch the shared generator gave: the ``DataLoader`` iterator's base seed (one int64
    draw), then ``RandomSampler``'s permutation, and a second, unused permutation when the epoch
    ran to its end (it closes the sampler's iterator; an epoch cut short by
    ``train_batches_per_epoch`` never gets there): ``full_epochs`` says which. ``skip``: indices
    to leave out at the start of the next iteration (set by a resume).
    """

    def __init__(self, n: int, seed: int, full_epochs: bool):
        self.n, self.seed, self.draws_per_epoch = int(n), int(seed), 2 if full_epochs else 1
        self.epoch, self.skip = 0, 0
        self.worker_seeds = torch.Generator().manual_seed(self.seed)  # the loader's base seeds, off the global RNG
        self._start = (0, torch.Generator().manual_seed(self.seed).get_state())  # generator state at an epoch's start

    def set_epoch(self, epoch: int) -> None:  # called by Lightning at the start of every epoch
        self.epoch = int(epoch)

    def order(self, epoch: int) -> torch.Tensor:
        e, state = self._start
        g = torch.Generator()
        if e <= epoch:
            g.set_state(state)  # go on from the last epoch computed (one epoch's draws, not all before it)
        else:
            e = 0
            g.manual_seed(self.seed)
        while True:
            torch.empty((), dtype=torch.int64).random_(generator=g)  # the loader iterator's base seed
            perm = torch.randperm(self.n, generator=g)
            if e == epoch:
                break
            if self.draws_per_epoch == 2:
                torch.randperm(self.n, generator=g)
            e += 1
            self._start = (e, g.get_state())
        return perm

    def __iter__(self):
        skip, self.skip = self.skip, 0
        yield from self.order(self.epoch)[skip:].tolist()

    def __len__(self) -> int:
        return self.n


class ResumableLoader(DataLoader):
    """A training ``DataLoader`` whose position Lightning stores in every checkpoint.

    ``progress()`` gives the batches of the current epoch already trained on; a resumed run
    skips them, so a run killed at any step and resumed ends with the same weights as one that
    never stopped.
    """

    def __init__(self, *args, progress=None, epoch_batches=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.progress = progress
        self.epoch_batches = epoch_batches  # batches an epoch trains on (train_batches_per_epoch or all)

    def state_dict(self) -> dict:
        return {"epoch": self.sampler.epoch, "batches": int(self.progress()) if self.progress else 0}

    def load_state_dict(self, state: dict) -> None:
        epoch, batches = int(state["epoch"]), int(state["batches"])
        if self.epoch_batches is not None and batches >= self.epoch_batches:
            epoch, batches = epoch + 1, 0  # saved on the epoch's last batch: Lightning goes on with the next epoch
        self.sampler.set_epoch(epoch)
        self.sampler.skip = batches * self.batch_size


class TrackWindowDataModule(L.LightningDataModule):
    """Train / val / test windows of a dataset written by ``pmsr simulate``.

    Batches are ``(z, x)`` with ``z (B, window, dim_z)`` and ``x (B, window, dim_x)``, float32,
    normalised to [-1, 1] with statistics fitted on the training tracks only. The scalers are
    :attr:`measurement_scaler` and :attr:`state_scaler` (physical units back with
    ``denormalise``). Training batches are shuffled with a generator seeded by ``seed``.

    ``fold``/``folds``: cross-validation for model selection. The dataset's train and val tracks
    are pooled and cut into ``folds`` parts by a permutation seeded from the dataset seed; part
    ``fold`` validates, the rest train, and the normalisation is refitted on those training
    tracks. The test split is never touched.

    ``eval_window_stride``: validation and test use every ``s``-th window (windows overlap by all
    but one sample, so a stride of 10 still covers every track evenly at a tenth of the cost).
    """

    def __init__(self, path: str | Path, window: int | None = None, batch_size: int = 256,
                 num_workers: int = 0, seed: int = 0, normalise: bool = True,
                 fold: int | None = None, folds: int | None = None, eval_window_stride: int = 1,
                 representation: Callable[["TrackWindowDataModule"], object] | None = None):
        """``representation``: called with this module once its normalisation is fitted, it gives
        what the windows hold (an object with ``encode(z, x)``, ``extra_context`` and
        ``to_dict()``, e.g. :func:`pmsr_nn.nets.representation.fit_on_training_tracks` bound to a
        model config); none: the paper's normalised rows."""
        super().__init__()
        self.path = Path(path)
        self.data = open_dataset(self.path)
        self.window = int(window or self.data.manifest["window"])
        self.batch_size = batch_size
        self.num_workers = num_workers
        self.seed = seed
        self.normalise = normalise
        self.eval_window_stride = int(eval_window_stride)
        self.tracks = {s: self.data.split_indices(s) for s in ("train", "val", "test")}
        if not len(self.tracks["train"]):  # a dataset without splits (pmsr simulate --no-splits, or few tracks)
            self.data.close()
            what, why = (("train/val split", f"all its {len(self.tracks['test'])} tracks are test tracks, for tracking "
                          "only") if not len(self.tracks["val"]) else ("train split", "no track to train on"))
            raise ConfigError(f"dataset {self.path} has no {what} ({why}); simulate more tracks")
        self.measurement_scaler: MinMaxScaler = self.data.scaler("measurements")
        self.state_scaler: MinMaxScaler = self.data.scaler("states")
        if folds is not None and folds > 1:
            self._use_fold(int(fold or 0), int(folds))
        self.representation = representation(self) if representation is not None else None
        self._sets: dict[str, WindowDataset] = {}

    def _use_fold(self, fold: int, folds: int) -> None:
        pool = np.concatenate([self.tracks["train"], self.tracks["val"]])
        if not 0 <= fold < folds:
            raise ConfigError(f"data fold {fold} is outside 0..{folds - 1}")
        if len(pool) < folds:
            raise ConfigError(f"{len(pool)} train+val tracks cannot be cut into {folds} folds; simulate more tracks")
        g = torch.Generator().manual_seed(int(self.data.manifest["seed"]) + 7919)
        pool = pool[torch.randperm(len(pool), generator=g).numpy()]
        parts = np.array_split(pool, folds)
        self.tracks["val"] = np.sort(parts[fold])
        self.tracks["train"] = np.sort(np.concatenate([p for i, p in enumerate(parts) if i != fold]))
        f, train = self.data.file, self.tracks["train"]  # sorted, as h5py's fancy indexing needs
        mm_z, mm_x = RunningMinMax(f["measurements"].shape[-1]), RunningMinMax(f["states"].shape[-1])
        mm_z.update(f["measurements"][train])
        mm_x.update(f["states"][train])
        self.measurement_scaler, self.state_scaler = mm_z.scaler(), mm_x.scaler()

    @property
    def manifest(self) -> dict:
        return self.data.manifest

    def normalisation(self) -> dict:
        """The statistics in force, as stored in a checkpoint."""
        norm = {"fitted_on": "train", "states": self.state_scaler.to_dict(),
                "measurements": self.measurement_scaler.to_dict()}
        if self.representation is not None:
            norm["representation"] = self.representation.to_dict()
        return norm

    def dataset(self, split: str) -> WindowDataset:
        if split not in self._sets:
            self._sets[split] = WindowDataset(self.data, split, self.window, normalise=self.normalise,
                                              tracks=self.tracks[split],
                                              scalers=(self.measurement_scaler, self.state_scaler),
                                              representation=self.representation)
        return self._sets[split]

    def setup(self, stage: str | None = None) -> None:
        splits = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",)}.get(stage or "", ("train", "val", "test"))
        for s in splits:
            self.dataset(s)

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        data = self.dataset(split)
        if not shuffle and self.eval_window_stride > 1:
            data = Subset(data, range(0, len(data), self.eval_window_stride))
        return DataLoader(data, batch_size=self.batch_size, shuffle=False,
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0)

    def train_dataloader(self) -> DataLoader:
        data = self.dataset("train")
        trainer = self.trainer
        limit = trainer.limit_train_batches if trainer is not None else 1.0
        full = limit >= 1.0 if isinstance(limit, float) else limit * self.batch_size >= len(data)
        batches = -(-len(data) // self.batch_size)
        epoch_batches = int(limit * batches) if isinstance(limit, float) else min(int(limit), batches)
        progress = (lambda: trainer.fit_loop.epoch_loop.batch_progress.current.processed) if trainer else None
        sampler = EpochShuffler(len(data), self.seed, full)
        return ResumableLoader(data, batch_size=self.batch_size, sampler=sampler, generator=sampler.worker_seeds,
                               num_workers=self.num_workers, persistent_workers=self.num_workers > 0,
                               progress=progress, epoch_batches=epoch_batches)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
