"""On-disk datasets, sliding windows, normalisation and the LightningDataModule."""

from .normalise import MinMaxScaler
from .store import TrackDataset, open_dataset, write_dataset
from .windows import WindowDataset, windows_per_track

__all__ = ["MinMaxScaler", "TrackDataset", "open_dataset", "write_dataset", "WindowDataset", "windows_per_track"]
