"""The ``LightningDataModule`` serving normalised (measurement window, state window) pairs."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import torch
from torch.utils.data import DataLoader

from .normalise import MinMaxScaler
from .store import open_dataset
from .windows import WindowDataset


class TrackWindowDataModule(L.LightningDataModule):
    """Train / val / test windows of a dataset written by ``pmsr simulate``.

    Batches are ``(z, x)`` with ``z (B, window, dim_z)`` and ``x (B, window, dim_x)``, float32,
    normalised to [-1, 1] with statistics fitted on the training split only. The scalers are
    :attr:`measurement_scaler` and :attr:`state_scaler` (physical units back with
    ``denormalise``). Training batches are shuffled with a generator seeded by ``seed``.
    """

    def __init__(self, path: str | Path, window: int | None = None, batch_size: int = 256,
                 num_workers: int = 0, seed: int = 0, normalise: bool = True):
        super().__init__()
        self.path = Path(path)
        self.data = open_dataset(self.path)
        self.window = int(window or self.data.manifest["window"])
        self.batch_size = batch_size
        self.num_workers = num_workers
        self.seed = seed
        self.normalise = normalise
        self.measurement_scaler: MinMaxScaler = self.data.scaler("measurements")
        self.state_scaler: MinMaxScaler = self.data.scaler("states")
        self._sets: dict[str, WindowDataset] = {}

    @property
    def manifest(self) -> dict:
        return self.data.manifest

    def dataset(self, split: str) -> WindowDataset:
        if split not in self._sets:
            self._sets[split] = WindowDataset(self.data, split, self.window, normalise=self.normalise)
        return self._sets[split]

    def setup(self, stage: str | None = None) -> None:
        splits = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",)}.get(stage or "", ("train", "val", "test"))
        for s in splits:
            self.dataset(s)

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        g = torch.Generator().manual_seed(self.seed) if shuffle else None
        return DataLoader(self.dataset(split), batch_size=self.batch_size, shuffle=shuffle, generator=g,
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0)

    def train_dataloader(self) -> DataLoader:
        return self._loader("train", shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader("val", shuffle=False)

    def test_dataloader(self) -> DataLoader:
        return self._loader("test", shuffle=False)
