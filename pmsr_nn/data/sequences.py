"""Measurement sequences in, state estimates out: the file formats of ``pmsr track``.

Inputs:
  * a CSV file with a header row naming the measurement columns (``range_1 .. azimuth_3``, SI
    units: m, m/s, rad), one row per scan, optionally a ``track`` column holding several
    sequences (rows of one track in time order; tracks may differ in length). Empty cells and
    ``nan`` are missing values. A file without a header is read when it has exactly the expected
    number of numeric columns, in the expected order.
  * a dataset directory written by ``pmsr simulate``, or its ``tracks.h5`` (the geometry and
    columns of its manifest are checked against the checkpoint), all tracks or one split.

Outputs (written atomically): ``.csv`` with ``track``, ``k`` and the state columns, one row per
input row in the input's order; or ``.h5`` with ``estimates (N, K, dim_x)``, ``track`` ids and the
columns as an attribute.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..errors import MeasurementError
from ..outputs import atomic_file


@dataclass
class Sequences:
    """Measurement sequences grouped by track: ``z[i] (K_i, D)`` for ``track[i]``."""

    z: list[torch.Tensor]
    track: list[str]
    rows: list[np.ndarray]  # input row numbers of each track's samples (to write back in order)
    source: dict = field(default_factory=dict)  # geometry / columns / dt_s when the input says

    def by_length(self):
        """``(length, indices)`` groups that can be tracked as one batch."""
        groups: dict[int, list[int]] = {}
        for i, z in enumerate(self.z):
            groups.setdefault(len(z), []).append(i)
        return groups.items()


def _number(cell: str, where: str) -> float:
    cell = cell.strip()
    if cell == "" or cell.lower() == "nan":
        return math.nan
    try:
        return float(cell)
    except ValueError:
        raise MeasurementError(f"{where}: {cell!r} is not a number") from None


def read_csv(path: Path, columns: list[str]) -> Sequences:
    """Read measurement rows in the order ``columns`` from a CSV file."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MeasurementError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")  # spreadsheet programs start their CSV files with a byte-order mark
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise MeasurementError(f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} on line {line}); "
                               "save it as UTF-8 CSV") from None
    if "\0" in text:
        raise MeasurementError(f"{path} is a binary file, not a CSV")
    lines = list(csv.reader(text.splitlines()))
    lines = [ln for ln in lines if ln and any(c.strip() for c in ln)]
    if not lines:
        raise MeasurementError(f"{path} holds no rows")
    head = [c.strip() for c in lines[0]]
    try:
        [float(c) for c in head]
        header, body, first = None, lines, 1
    except ValueError:
        header, body, first = head, lines[1:], 2
    if header is None:
        if len(head) != len(columns):
            raise MeasurementError(f"{path}: {len(head)} columns and no header; the checkpoint expects "
                                   f"{len(columns)} ({', '.join(columns)})")
        header = list(columns)
    twice = sorted({c for c in header if header.count(c) > 1})
    if twice:
        raise MeasurementError(f"{path}: duplicate column {twice[0]!r} in the header")
    missing = [c for c in columns if c not in header]
    unknown = [c for c in header if c not in columns and c not in ("track", "k", "time_s")]
    if missing or unknown:
        raise MeasurementError(f"{path}: columns {header} do not match the checkpoint's {columns}"
                               + (f" (missing {missing})" if missing else "") + (f" (unknown {unknown})" if unknown else ""))
    if not body:
        raise MeasurementError(f"{path} has a header but no measurement rows")
    idx = [header.index(c) for c in columns]
    tcol = header.index("track") if "track" in header else None
    time_col = header.index("time_s") if "time_s" in header else None
    values = np.empty((len(body), len(columns)))
    times = np.full(len(body), np.nan)
    tracks: list[str] = []
    for r, row in enumerate(body):
        where = f"{path}, line {r + first}"
        if len(row) != len(header):
            raise MeasurementError(f"{where}: {len(row)} cells, the header has {len(header)}")
        values[r] = [_number(row[i], where) for i in idx]
        if time_col is not None:
            times[r] = _number(row[time_col], where)
        tracks.append(row[tcol].strip() if tcol is not None else "0")
    order: dict[str, list[int]] = {}
    for r, t in enumerate(tracks):
        order.setdefault(t, []).append(r)
    rows = [np.asarray(v) for v in order.values()]
    source = {"columns": list(columns)}
    if time_col is not None:
        source["dt_s"] = _sampling_interval(path, times, rows, list(order), first)
    return Sequences([torch.from_numpy(values[r]) for r in rows], list(order), rows, source)


def _sampling_interval(path: Path, times: np.ndarray, rows: list[np.ndarray], tracks: list[str], first: int) -> float | None:
    """The one sampling interval (s) of a ``time_s`` column; refused when it is uneven or differs between tracks."""
    dt = None
    for t, r in zip(tracks, rows):
        d = np.diff(times[r])
        if len(d) == 0:
            continue
        if not np.isfinite(d).all() or (d <= 0).any():
            k = int(np.flatnonzero(~(np.isfinite(d) & (d > 0)))[0])
            raise MeasurementError(f"{path}, line {int(r[k + 1]) + first}: time_s of track {t!r} does not increase")
        step = float(np.median(d))
        uneven = np.abs(d - step) > 1e-6 * step + 1e-9
        if uneven.any():
            k = int(np.flatnonzero(uneven)[0])
            raise MeasurementError(f"{path}, line {int(r[k + 1]) + first}: time_s of track {t!r} jumps by {d[k]:g} s "
                                   f"where the track is sampled every {step:g} s (missed scans: give them as NaN rows)")
        if dt is not None and abs(step - dt) > 1e-6 * dt:
            raise MeasurementError(f"{path}: track {t!r} is sampled every {step:g} s, another every {dt:g} s")
        dt = step
    return dt


def read_dataset(path: Path, split: str | None = None) -> Sequences:
    """Measurement sequences of a dataset directory (all tracks, or one split)."""
    from .store import open_dataset

    ds = open_dataset(path)
    try:
        m = ds.manifest
        ids = ds.split_indices(split) if split else np.arange(m["shapes"]["measurements"][0])
        z = torch.from_numpy(ds.file["measurements"][np.sort(ids)].astype(np.float64)) if len(ids) else None
        unsplit = z is None and not ds.has_splits()
    finally:
        ds.close()
    if unsplit:
        raise MeasurementError(f"{path} has no {split} split: all its tracks are test tracks (simulated without "
                               "splits); use --split test or leave --split out")
    if z is None:
        raise MeasurementError(f"{path}: split {split!r} holds no tracks")
    K = z.shape[1]
    rows = [np.arange(i * K, (i + 1) * K) for i in range(len(ids))]
    source = {"geometry": m["geometry"], "columns": m["columns"]["measurements"], "dt_s": m["dt_s"]}
    return Sequences(list(z.unbind(0)), [str(int(i)) for i in np.sort(ids)], rows, source)


def read_measurements(path: str | Path, columns: list[str], split: str | None = None) -> Sequences:
    """A CSV file, a dataset directory or the dataset's ``tracks.h5``; see the module docstring."""
    from .store import ARRAYS, MANIFEST, is_our_dataset

    path = Path(path)
    if path.is_dir():
        return read_dataset(path, split)
    if not path.is_file():
        raise MeasurementError(f"no measurement file at {path}")
    if path.name == ARRAYS and is_our_dataset(path.parent):
        return read_dataset(path.parent, split)  # the folder's manifest: geometry, columns, dt
    if path.name == MANIFEST and is_our_dataset(path.parent):
        raise MeasurementError(f"{path} is part of a dataset: give the dataset folder {path.parent} (or its "
                               f"{ARRAYS}) as --input")
    if path.suffix.lower() in (".h5", ".hdf5"):
        raise MeasurementError(f"{path} is not the {ARRAYS} of a pmsr_nn dataset folder; give a dataset folder, "
                               f"its {ARRAYS}, or a measurement CSV as --input")
    if path.suffix.lower() in (".json", ".npz", ".pt", ".ckpt"):
        raise MeasurementError(f"{path}: measurements are read from a CSV file or a dataset folder, "
                               f"not a {path.suffix} file")
    if split is not None:
        raise MeasurementError("--split applies to a dataset directory, not to a CSV file")
    return read_csv(path, columns)


def write_estimates(path: str | Path, seqs: Sequences, estimates: list[torch.Tensor], columns: list[str],
                    provenance: dict, *, overwrite: bool = False, inputs=()) -> Path:
    """Write estimates (one ``(K_i, dim_x)`` per sequence) as ``.csv`` or ``.h5``, atomically.

    An existing ``path`` is replaced only with ``overwrite``, and never when it is one of ``inputs``.
    """
    path = Path(path)
    with atomic_file(path, overwrite=overwrite, inputs=inputs, suffixes=(".csv", ".h5")) as tmp:
        if path.suffix.lower() == ".csv":
            n = sum(len(r) for r in seqs.rows)
            out = [None] * n
            for t, rows, est in zip(seqs.track, seqs.rows, estimates):
                for k, (r, x) in enumerate(zip(rows, est.tolist())):
                    out[r] = [t, k, *(f"{v:.6f}" for v in x)]
            with open(tmp, "w", newline="") as f:
                w = csv.writer(f)
                w.writerow(["track", "k", *columns])
                w.writerows(out)
        else:
            import h5py

            lengths = {len(e) for e in estimates}
            with h5py.File(tmp, "w") as h5:
                if len(lengths) == 1:
                    h5.create_dataset("estimates", data=torch.stack(estimates).numpy())
                else:
                    for t, e in zip(seqs.track, estimates):
                        h5.create_dataset(f"estimates/{t}", data=e.numpy())
                h5.create_dataset("track", data=np.array(seqs.track, dtype="S"))
                h5.attrs["columns"] = json.dumps(columns)
                h5.attrs["provenance"] = json.dumps(provenance)
    return path


def write_csv_measurements(path: str | Path, z: torch.Tensor, columns: list[str], *, overwrite: bool = False,
                           inputs=()) -> Path:
    """Measurements ``(B, K, D)`` as a CSV with a ``track`` column (what ``pmsr track`` reads), atomically."""
    path = Path(path)
    with atomic_file(path, overwrite=overwrite, inputs=inputs, suffixes=(".csv",)) as tmp:
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["track", *columns])
            for b, seq in enumerate(z.tolist()):
                w.writerows([b, *(repr(v) for v in row)] for row in seq)
    return path
