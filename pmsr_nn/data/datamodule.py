"""The ``LightningDataModule`` serving normalised (measurement window, state window) pairs."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Subset

from ..errors import ConfigError
from .normalise import MinMaxScaler, RunningMinMax
from .store import open_dataset
from .windows import WindowDataset


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
                 fold: int | None = None, folds: int | None = None, eval_window_stride: int = 1):
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
        self.measurement_scaler: MinMaxScaler = self.data.scaler("measurements")
        self.state_scaler: MinMaxScaler = self.data.scaler("states")
        if folds is not None and folds > 1:
            self._use_fold(int(fold or 0), int(folds))
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
        return {"fitted_on": "train", "states": self.state_scaler.to_dict(),
                "measurements": self.measurement_scaler.to_dict()}

    def dataset(self, split: str) -> WindowDataset:
        if split not in self._sets:
            self._sets[split] = WindowDataset(self.data, split, self.window, normalise=self.normalise,
                                              tracks=self.tracks[split],
                                              scalers=(self.measurement_scaler, self.state_scaler))
        return self._sets[split]

    def setup(self, stage: str | None = None) -> None:
        splits = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",)}.get(stage or "", ("train", "val", "test"))
        for s in splits:
            self.dataset(s)

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        g = torch.Generator().manual_seed(self.seed) if shuffle else None
        data = self.dataset(split)
        if not shuffle and self.eval_window_stride > 1:
            data = Subset(data, range(0, len(data), self.eval_window_stride))
        return DataLoader(data, batch_size=self.batch_size, shuffle=shuffle, generator=g,
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
