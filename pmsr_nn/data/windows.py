"""Sliding windows over tracks (Algorithm 1 of the MDFNN paper), served lazily.

A window is addressed by ``(track, start)``; nothing is materialised until a window is asked
for. Per track of ``K`` samples there are ``K - window + 1`` windows, starts ``0 .. K - window``.
Algorithm 1 as printed loops ``n = 1 .. K - window`` and so stops one window short of the end
of the track; we keep that last full window.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import DatasetError
from .normalise import MinMaxScaler
from .store import TrackDataset, open_dataset

IN_MEMORY_LIMIT_BYTES = 2 * 1024**3
"""Splits smaller than this are read into memory once (still never windowed in advance)."""


def windows_per_track(steps: int, window: int) -> int:
    """Number of full windows of ``window`` samples in a track of ``steps`` samples."""
    if window > steps:
        raise DatasetError(f"window of {window} samples is longer than the tracks ({steps} samples)")
    return steps - window + 1


class WindowDataset(Dataset):
    """(input window, target window) pairs of one split: by default the measurement and state
    windows normalised to [-1, 1]; with a ``representation``, what that network reads and predicts.

    Item ``i`` is window ``i % windows_per_track`` of the split's track ``i // windows_per_track``:
    ``z (window, dim_z)`` and ``x (window, dim_x)`` as float32 (``dtype``). The scalers fitted on
    the training split are :attr:`measurement_scaler` and :attr:`state_scaler`; use
    ``state_scaler.denormalise`` to get metres back.
    """

    def __init__(self, dataset: TrackDataset | str, split: str, window: int | None = None,
                 normalise: bool = True, dtype: torch.dtype = torch.float32, in_memory: bool | None = None,
                 tracks: np.ndarray | None = None, scalers: tuple[MinMaxScaler, MinMaxScaler] | None = None,
                 representation=None):
        """``tracks`` (file indices) replaces the split's own tracks and ``scalers``
        (measurements, states) the manifest's statistics, for cross-validation folds.
        ``representation`` (:class:`~pmsr_nn.nets.representation.Representation`) turns each
        track into network inputs and targets; none: the min-max normalised rows (the paper's)."""
        self.data = open_dataset(dataset) if not isinstance(dataset, TrackDataset) else dataset
        man = self.data.manifest
        self.split = split
        self.window = int(window or man["window"])
        self.steps = man["shapes"]["states"][1]
        self.per_track = windows_per_track(self.steps, self.window)
        self.tracks = np.asarray(tracks) if tracks is not None else self.data.split_indices(split)
        self.normalise = normalise
        self.dtype = dtype
        if scalers is None:
            scalers = (self.data.scaler("measurements"), self.data.scaler("states"))
        self.measurement_scaler, self.state_scaler = scalers
        row_bytes = np.dtype(man["dtype"]).itemsize * self.steps * (
            man["shapes"]["states"][2] + man["shapes"]["measurements"][2]
        )
        if in_memory is None:
            in_memory = row_bytes * len(self.tracks) <= IN_MEMORY_LIMIT_BYTES
        self.representation = representation if normalise else None
        self._cache = None
        self._encoded = False
        if in_memory and len(self.tracks):
            f = self.data.file
            z = torch.from_numpy(f["measurements"][self.tracks])
            x = torch.from_numpy(f["states"][self.tracks])
            if self.representation is not None:  # whole tracks encoded once (local features read k - 1)
                u, y = self.representation.encode(z, x)
                z, x, self._encoded = u.to(dtype), y.to(dtype), True
            self._cache = (z, x)

    def __len__(self) -> int:
        return len(self.tracks) * self.per_track

    def locate(self, i: int) -> tuple[int, int]:
        """Window ``i`` -> (track index in the file, start sample)."""
        if not 0 <= i < len(self):
            raise IndexError(f"window {i} out of range for {len(self)} windows")
        return int(self.tracks[i // self.per_track]), i % self.per_track

    def _finish(self, z: torch.Tensor, x: torch.Tensor):
        if self._encoded:
            return z, x
        z, x = z.to(torch.float64), x.to(torch.float64)
        if self.representation is not None:  # a window read from disk, with one scan before it when it has one
            u, y = self.representation.encode(z[None], x[None])
            lead = len(z) - self.window
            return u[0, lead:].to(self.dtype), y[0, lead:].to(self.dtype)
        if self.normalise:
            z, x = self.measurement_scaler.normalise(z), self.state_scaler.normalise(x)
        return z.to(self.dtype), x.to(self.dtype)

    def __getitem__(self, i: int):
        track, start = self.locate(int(i))
        sl = slice(start, start + self.window)
        if self._cache is not None:
            row = i // self.per_track
            return self._finish(self._cache[0][row, sl], self._cache[1][row, sl])
        f = self.data.file
        if self.representation is not None and self.representation.extra_context:
            sl = slice(max(0, start - self.representation.extra_context), start + self.window)
        return self._finish(torch.from_numpy(f["measurements"][track, sl]), torch.from_numpy(f["states"][track, sl]))

    def __getitems__(self, indices):
        """A whole batch by one gather (used by ``DataLoader`` when present); returns a list of pairs."""
        if self._cache is None:
            return [self[i] for i in indices]
        idx = torch.as_tensor(indices, dtype=torch.long)
        if len(idx) and (int(idx.min()) < 0 or int(idx.max()) >= len(self)):
            raise IndexError("window index out of range")
        rows, starts = idx // self.per_track, idx % self.per_track
        t = starts[:, None] + torch.arange(self.window)
        z, x = self._finish(self._cache[0][rows[:, None], t], self._cache[1][rows[:, None], t])
        return list(zip(z.unbind(0), x.unbind(0)))
