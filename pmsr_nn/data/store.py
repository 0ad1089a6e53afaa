"""The track dataset on disk: an HDF5 file plus a JSON manifest, written atomically.

Layout of a dataset directory::

    DIR/manifest.json   format, package version, full recipe, seed, shapes, column names and
                        units, split sizes, normalisation statistics (training split only; all
                        tracks in a dataset without splits), envelope statistics, SHA-256 of
                        every array
    DIR/tracks.h5       states (N, K, dim_x), measurements (N, K, dim_z), noise_std (N, 3),
                        split (N,) 0/1/2 = train/val/test, violations (N, 3) bool
                        (range, speed, azimuth), and the manifest again as an attribute

HDF5 opens in MATLAB (``h5read``) and every other language; MATLAB shows the axes reversed
(``K x dim x N``) because it is column-major. Arrays are chunked one track per chunk, so a window
of one track is a single small read.

Atomicity: everything is written through :func:`pmsr_nn.outputs.atomic_folder`, into a hidden
sibling ``.DIR.partial-PID`` renamed to ``DIR`` only after the last byte and the manifest are on
disk. A failed or interrupted run removes it; a killed one leaves only the hidden folder, which no
reader accepts and the next write of ``DIR`` removes. Only a folder that is one of our datasets
is ever replaced (``overwrite``).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import torch
from tqdm.auto import tqdm

from .. import __version__, interrupts
from ..errors import DatasetError, PmsrError
from ..outputs import DATASET_FORMAT, DATASET_MANIFEST, atomic_folder, check_folder_target, is_our_dataset
from ..rng import seeded_generator
from ..simulation.recipe import TrackRecipe
from ..simulation.tracks import ENVELOPE_CRITERIA, DrawStats, build_models, generate_tracks
from .normalise import MinMaxScaler, RunningMinMax

FORMAT, MANIFEST = DATASET_FORMAT, DATASET_MANIFEST
FORMAT_VERSION = 1
ARRAYS = "tracks.h5"
SPLITS = ("train", "val", "test")
_SPLIT_STREAM, _CHUNK_STREAM = 1, 2


def state_columns(dim: int) -> list[str]:
    axes = "xyz"[:dim]
    return [f"{q}{a}" for a in axes for q in ("", "v", "a")]


def check_output_path(out: Path, overwrite: bool, inputs=(), what: str = "--out") -> None:
    """Refuse to write over anything that is not one of our datasets (and over ours unless asked),
    and every output :func:`pmsr_nn.outputs.check_folder_target` refuses (a virtual file system
    included); :func:`check_disk_space` is the check of the room on the disk."""
    out = Path(out)
    if out.exists() and not out.is_symlink() and (not out.is_dir() or any(out.iterdir())) and not is_our_dataset(out):
        raise DatasetError(f"output path {out} exists and is not a pmsr_nn dataset; choose another path")
    check_folder_target(out, overwrite=overwrite, inputs=inputs, allow=("simulate",), what=what)


def dataset_bytes(recipe: TrackRecipe) -> int:
    """Bytes the arrays of ``recipe``'s dataset take on disk (uncompressed)."""
    motion, meas = build_models(recipe)
    item = np.dtype(recipe.storage.dtype).itemsize
    return recipe.tracks * (recipe.motion.steps * (motion.dim_x + meas.dim_z) * item + 3 * 8 + 1 + 3)


def check_disk_space(recipe: TrackRecipe, out: Path, what: str = "--out") -> None:
    """Refuse a dataset larger than the free space of the disk that would hold it."""
    need = dataset_bytes(recipe)
    anc = Path(os.path.abspath(out)).parent
    while not anc.exists():
        anc = anc.parent
    usage = shutil.disk_usage(anc)
    if usage.total == 0:  # no size to compare with (ramfs); /proc and /sys were refused by check_output_path
        return
    if need > usage.free:
        raise DatasetError(f"{what} {out}: {recipe.tracks:,} tracks x {recipe.motion.steps} steps need {_size(need)} and "
                           f"{anc} has {_size(usage.free)} free: ask for fewer tracks, or give a folder on a roomier disk")


def _size(n: int) -> str:
    """Bytes as a short human figure: 1.2 kB, 3.4 MB, 5.6 GB."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:,.1f} {unit}"
    return f"{n} bytes"


def assign_splits(recipe: TrackRecipe) -> np.ndarray:
    """Split code per track (0 train, 1 val, 2 test): a seeded permutation of whole tracks."""
    n_train, n_val, _ = recipe.splits.counts(recipe.tracks)
    perm = torch.randperm(recipe.tracks, generator=seeded_generator(recipe.seed, _SPLIT_STREAM)).numpy()
    code = np.full(recipe.tracks, 2, dtype=np.uint8)
    code[perm[:n_train]] = 0
    code[perm[n_train : n_train + n_val]] = 1
    return code


def write_dataset(recipe: TrackRecipe, out: str | Path, *, overwrite: bool = False, progress: bool = True,
                  inputs=(), what: str = "--out") -> dict:
    """Generate the recipe's tracks chunk by chunk and write them atomically to ``out``.

    Memory stays bounded by ``storage.chunk_tracks`` however many tracks are asked for. Returns
    the manifest. ``inputs``: files the command read (never written over).
    """
    out = Path(out)
    check_output_path(out, overwrite, inputs, what)
    check_disk_space(recipe, out, what)
    with atomic_folder(out, command="simulate", overwrite=overwrite, inputs=inputs, allow=("simulate",), what=what) as tmp:
        return _write_into(recipe, tmp, progress)


def _write_into(recipe: TrackRecipe, tmp: Path, progress: bool) -> dict:
    motion, meas = build_models(recipe)
    n, K = recipe.tracks, recipe.motion.steps
    dtype = np.dtype(recipe.storage.dtype)
    split = assign_splits(recipe)
    fit = split == 0 if not recipe.splits.is_none else np.ones(n, dtype=bool)  # normalisation: train (or all) tracks
    shapes = {"states": (n, K, motion.dim_x), "measurements": (n, K, meas.dim_z), "noise_std": (n, 3)}
    digests = {name: hashlib.sha256() for name in ("states", "measurements", "noise_std", "split", "violations")}
    mm_z, mm_x = RunningMinMax(meas.dim_z), RunningMinMax(motion.dim_x)
    stats = DrawStats()
    violations = np.zeros((n, len(ENVELOPE_CRITERIA)), dtype=bool)
    chunk = recipe.storage.chunk_tracks
    with h5py.File(tmp / ARRAYS, "w") as h5:
        dsets = {
            name: h5.create_dataset(name, shape, dtype=dtype if name != "noise_std" else np.float64,
                                    chunks=(1, *shape[1:]) if len(shape) == 3 else None)
            for name, shape in shapes.items()
        }
        with tqdm(total=n, unit="track", desc=f"simulate {recipe.name}", disable=None if progress else True, leave=False) as bar:
            for c, start in enumerate(range(0, n, chunk)):
                interrupts.check()
                stop = min(start + chunk, n)
                batch, st = generate_tracks(recipe, stop - start, seeded_generator(recipe.seed, _CHUNK_STREAM, c))
                stats.add(st)
                arrays = {
                    "states": batch.states.numpy().astype(dtype),
                    "measurements": batch.measurements.numpy().astype(dtype),
                    "noise_std": batch.noise_std.numpy(),
                }
                for name, arr in arrays.items():
                    dsets[name][start:stop] = arr
                    digests[name].update(np.ascontiguousarray(arr).tobytes())
                mm_z.update(arrays["measurements"][fit[start:stop]])
                mm_x.update(arrays["states"][fit[start:stop]])
                violations[start:stop] = np.stack([batch.violations[k].numpy() for k in ENVELOPE_CRITERIA], -1)
                bar.update(stop - start)
        h5.create_dataset("split", data=split)
        h5.create_dataset("violations", data=violations)
        digests["split"].update(split.tobytes())
        digests["violations"].update(violations.tobytes())
        for name, cols in (("states", state_columns(recipe.dim)), ("measurements", meas.labels),
                           ("noise_std", ["range_m", "range_rate_mps", "azimuth_rad"])):
            h5[name].attrs["columns"] = json.dumps(cols)
        h5["violations"].attrs["columns"] = json.dumps(list(ENVELOPE_CRITERIA))
        manifest = _manifest(recipe, shapes, dtype, split, violations, stats, mm_x.scaler(), mm_z.scaler(), meas, digests)
        h5.attrs["format"] = FORMAT
        h5.attrs["manifest"] = json.dumps(manifest)
    (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def _manifest(recipe, shapes, dtype, split, violations, stats, scaler_x, scaler_z, meas, digests) -> dict:
    counts = {name: int((split == i).sum()) for i, name in enumerate(SPLITS)}
    left = violations.any(-1)
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "pmsr_nn_version": __version__,
        "name": recipe.name,
        "seed": recipe.seed,
        "variant": recipe.variant,
        "recipe": recipe.to_dict(),
        "geometry": meas.geometry.to_dict(),
        "dtype": dtype.name,
        "shapes": {k: list(v) for k, v in shapes.items()},
        "columns": {
            "states": state_columns(recipe.dim),
            "measurements": meas.labels,
            "noise_std": ["range_m", "range_rate_mps", "azimuth_rad"],
        },
        "units": "SI: m, m/s, m/s^2, rad; azimuth clockwise from north at the receiver; range-rate dr/dt",
        "dt_s": recipe.motion.dt_s,
        "window": recipe.window,
        "windows_per_track": recipe.windows_per_track,
        "splits": counts,
        "windows": {k: v * recipe.windows_per_track for k, v in counts.items()},
        "normalisation": {"fitted_on": "all" if recipe.splits.is_none else "train", "states": scaler_x.to_dict(),
                          "measurements": scaler_z.to_dict()},
        "envelope": {
            "fraction_left": float(left.mean()),
            "fraction_left_by_criterion": {k: float(violations[:, i].mean()) for i, k in enumerate(ENVELOPE_CRITERIA)},
            "draws": vars(stats).copy(),
            "acceptance": stats.acceptance,
        },
        "checksums_sha256": {k: d.hexdigest() for k, d in digests.items()},
    }


@dataclass
class TrackDataset:
    """A dataset directory opened for reading; arrays are read lazily from HDF5."""

    path: Path
    manifest: dict

    @property
    def file(self) -> h5py.File:
        if getattr(self, "_h5", None) is None:
            self._h5 = h5py.File(self.path / ARRAYS, "r")
        return self._h5

    def close(self) -> None:
        if getattr(self, "_h5", None) is not None:
            self._h5.close()
            self._h5 = None

    def __getstate__(self):  # h5py handles do not cross process boundaries (DataLoader workers)
        return {"path": self.path, "manifest": self.manifest}

    @property
    def split(self) -> np.ndarray:
        return self.file["split"][()]

    def split_indices(self, name: str) -> np.ndarray:
        """Track indices of split ``name`` ('train', 'val' or 'test'), ascending."""
        if name not in SPLITS:
            raise DatasetError(f"unknown split {name!r}; choose one of {SPLITS}")
        return np.flatnonzero(self.split == SPLITS.index(name))

    def has_splits(self) -> bool:
        """False for a dataset without splits (every track a test track: ``pmsr simulate --no-splits``,
        or too few tracks for the recipe's split), which serves tracking, not training."""
        return bool((self.split != SPLITS.index("test")).any())

    def scaler(self, which: str) -> MinMaxScaler:
        """Normalisation fitted on the training split, for 'states' or 'measurements'."""
        return MinMaxScaler.from_dict(self.manifest["normalisation"][which])

    def recipe(self) -> TrackRecipe:
        from ..simulation.recipe import recipe_from_dict

        return recipe_from_dict(self.manifest["recipe"])

    def verify(self) -> None:
        """Recompute every checksum; raise :class:`DatasetError` on a mismatch."""
        for name, want in self.manifest["checksums_sha256"].items():
            h = hashlib.sha256()
            ds = self.file[name]
            step = 256
            for a in range(0, ds.shape[0], step):
                h.update(np.ascontiguousarray(ds[a : a + step]).tobytes())
            if h.hexdigest() != want:
                raise DatasetError(f"{self.path}: array '{name}' does not match its checksum (corrupted?)")


_MANIFEST_TYPES = {"name": str, "seed": int, "variant": str, "recipe": dict, "geometry": dict, "dtype": str,
                   "shapes": dict, "columns": dict, "dt_s": (int, float), "window": int, "windows_per_track": int,
                   "splits": dict, "windows": dict, "normalisation": dict, "envelope": dict, "checksums_sha256": dict}


def _check_manifest(m: dict, path: Path) -> None:
    """Refuse a manifest missing a key or holding a value of the wrong kind (edited or corrupted)."""
    where = f"{path}/{MANIFEST}"
    for key, kind in _MANIFEST_TYPES.items():
        if key not in m:
            raise DatasetError(f"{where} lacks '{key}' (edited or corrupted?)")
        if not isinstance(m[key], kind) or isinstance(m[key], bool):
            raise DatasetError(f"{where}: '{key}' has the wrong kind of value ({type(m[key]).__name__})")
    shapes = m["shapes"]
    for name, rank in (("states", 3), ("measurements", 3), ("noise_std", 2)):
        s = shapes.get(name)
        if not (isinstance(s, list) and len(s) == rank and all(isinstance(v, int) and v >= 0 for v in s)):
            raise DatasetError(f"{where}: shapes.{name} must be a list of {rank} sizes, got {s!r:.60}")
    if not m["dt_s"] > 0:
        raise DatasetError(f"{where}: dt_s must be positive, got {m['dt_s']}")
    for key in ("states", "measurements"):
        if not isinstance(m["columns"].get(key), list) or not isinstance(m["normalisation"].get(key), dict):
            raise DatasetError(f"{where}: columns.{key} or normalisation.{key} is missing")
    env = m["envelope"]
    if not all(isinstance(env.get(k), (int, float)) for k in ("fraction_left", "acceptance")) \
            or not isinstance(env.get("fraction_left_by_criterion"), dict):
        raise DatasetError(f"{where}: envelope statistics are missing")
    try:
        from ..geometry import Geometry

        Geometry.from_dict(m["geometry"])
    except PmsrError as exc:
        raise DatasetError(f"{where}: geometry: {exc}") from None


def open_dataset(path: str | Path) -> TrackDataset:
    """Open a dataset directory written by :func:`write_dataset`, checking it is complete and ours."""
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"no dataset at {path}")
    try:
        manifest = json.loads((path / MANIFEST).read_text())
    except OSError:
        raise DatasetError(f"{path} has no {MANIFEST}: not a pmsr_nn dataset, or an incomplete one") from None
    except ValueError:
        raise DatasetError(f"{path}/{MANIFEST} is not valid JSON (corrupted?)") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise DatasetError(f"{path} is not a pmsr_nn track dataset")
    if manifest.get("format_version") != FORMAT_VERSION:
        raise DatasetError(f"{path} has format version {manifest.get('format_version')}; this pmsr_nn reads {FORMAT_VERSION}")
    _check_manifest(manifest, path)
    ds = TrackDataset(path, manifest)
    try:
        f = ds.file
        for name, shape in manifest["shapes"].items():
            if list(f[name].shape) != shape:
                raise DatasetError(f"{path}: array '{name}' has shape {f[name].shape}, manifest says {shape}")
    except (OSError, KeyError) as exc:
        ds.close()
        raise DatasetError(f"{path}/{ARRAYS} is missing or unreadable ({exc})") from None
    except PmsrError:
        ds.close()
        raise
    return ds
