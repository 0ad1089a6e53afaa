"""Self-contained tracker checkpoints, read without unpickling arbitrary objects.

A checkpoint holds the network weights (``state_dict``, keys prefixed ``net.``) and a plain-data
``pmsr`` block: format and package version, the model config, the measurement and state
columns, the training window, the sampling interval, the scenario geometry and the
normalisation statistics. Lightning's own checkpoints of a training run carry the same block
(added in ``TrackerModule.on_save_checkpoint``), so both load here; the slim ``tracker.pt`` a
run exports holds only the block and the weights.

Everything is read with ``torch.load(weights_only=True)``: tensors, numbers, strings, lists and
dicts only. A file that needs anything else is refused, never executed.
"""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import torch

from .. import __version__
from ..config import from_dict, to_dict
from ..errors import CheckpointError, ConfigError
from ..outputs import atomic_file
from .config import ModelConfig

FORMAT = "pmsr_nn.tracker"
FORMAT_VERSION = 1
DETECTION_FORMATS = {"pmsr_nn.nebp": "nebp"}
"""Checkpoints of the trackers that read detections (format -> the method kind that reads them)."""
RETIRED_FORMATS = {"pmsr_nn.set_tracker": "the end-to-end set tracker, removed from the package under issue 56 "
                                          "(evaluate/RESULTS.md; its code is at commit 4699b3d)",
                   "pmsr_nn.jpda_gain": "the hybrid tracker (S-MSJPDA with a learned gain correction, kind "
                                        "jpda_learned_gain), removed from the package under issue 56 "
                                        "(evaluate/RESULTS.md; its code is at commit c270857)"}
"""Checkpoints of trackers this package no longer has (format -> what it was and where it lives):
refused in one line by every reader."""


def refuse_retired(meta, path: Path) -> None:
    """A one-line :class:`CheckpointError` where ``meta`` (a checkpoint's ``pmsr`` block) is of a
    format in ``RETIRED_FORMATS``."""
    fmt = meta.get("format") if isinstance(meta, dict) else None
    if isinstance(fmt, str) and fmt in RETIRED_FORMATS:
        raise CheckpointError(f"{path} is a checkpoint of {RETIRED_FORMATS[fmt]}; no command of this pmsr_nn reads it")


def tracker_metadata(model: ModelConfig, manifest: dict, normalisation: dict, **training) -> dict:
    """The ``pmsr`` block for a network trained on the dataset ``manifest`` describes.

    ``normalisation`` is ``{"states": {"min", "max"}, "measurements": {...}}`` as fitted on the
    tracks the network was trained on. ``training`` adds free-form plain-data facts (seed, fold).
    """
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "pmsr_nn_version": __version__,
        "model": to_dict(model),
        "dim_z": manifest["shapes"]["measurements"][2],
        "dim_x": manifest["shapes"]["states"][2],
        "window": int(training.pop("window", manifest["window"])),
        "dt_s": manifest["dt_s"],
        "geometry": manifest["geometry"],
        "measurement_columns": list(manifest["columns"]["measurements"]),
        "state_columns": list(manifest["columns"]["states"]),
        "normalisation": normalisation,
        "dataset": {k: manifest[k] for k in ("name", "seed", "variant")},
        "training": training,
    }


def save_tracker(path: str | Path, meta: dict, state_dict: dict) -> Path:
    """Write ``{'pmsr': meta, 'state_dict': ...}`` atomically (temporary file, then rename)."""
    return save_blob(path, meta, state_dict)


_META_TYPES = {"model": dict, "dim_z": int, "dim_x": int, "window": int, "dt_s": (int, float), "geometry": dict,
               "measurement_columns": list, "state_columns": list, "normalisation": dict}


def _check_meta(meta: dict, path: Path) -> None:
    """Refuse a ``pmsr`` block with a missing or ill-typed entry, or unusable normalisation."""
    import math

    for key, kind in _META_TYPES.items():
        if key not in meta:
            raise CheckpointError(f"{path}: the checkpoint's pmsr block lacks '{key}' (edited or corrupted?)")
        if not isinstance(meta[key], kind) or isinstance(meta[key], bool):
            raise CheckpointError(f"{path}: the checkpoint's '{key}' has the wrong kind of value")
    if meta["window"] < 1 or meta["dim_z"] < 1 or meta["dim_x"] < 1 or not meta["dt_s"] > 0:
        raise CheckpointError(f"{path}: the checkpoint's window, dimensions or dt_s are not positive")
    if len(meta["measurement_columns"]) != meta["dim_z"] or len(meta["state_columns"]) != meta["dim_x"]:
        raise CheckpointError(f"{path}: the checkpoint's columns do not match its dimensions")
    for which, dim in (("measurements", meta["dim_z"]), ("states", meta["dim_x"])):
        norm = meta["normalisation"].get(which)
        lo, hi = (norm.get("min"), norm.get("max")) if isinstance(norm, dict) else (None, None)
        ok = (isinstance(lo, list) and isinstance(hi, list) and len(lo) == len(hi) == dim
              and all(isinstance(v, (int, float)) and math.isfinite(v) for v in lo + hi)
              and all(b > a for a, b in zip(lo, hi)))
        if not ok:
            raise CheckpointError(f"{path}: the checkpoint's normalisation of the {which} is missing, not finite "
                                  "or empty (min >= max)")
    from ..geometry import Geometry

    try:
        Geometry.from_dict(meta["geometry"])
    except CheckpointError:
        raise
    except Exception as exc:
        raise CheckpointError(f"{path}: the checkpoint's geometry is unusable ({exc})") from None


def read_checkpoint(path: str | Path) -> tuple[dict, ModelConfig, dict]:
    """``(meta, model config, network state_dict)`` of a checkpoint, checked to be ours and whole."""
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(f"{path} is a folder; give its tracker.pt or a .ckpt file")
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    if path.stat().st_size == 0:
        raise CheckpointError(f"{path} is empty (0 bytes): an interrupted copy?")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise CheckpointError(f"{path} holds objects other than tensors and plain data; "
                              "refusing to unpickle it (only pmsr_nn checkpoints are loaded)") from None
    except (RuntimeError, EOFError, OSError, zipfile.BadZipFile, ValueError, TypeError, KeyError,
            IndexError, AttributeError, UnicodeDecodeError, MemoryError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:120]
        raise CheckpointError(f"{path} is not a readable torch checkpoint (truncated or corrupted?): {first}") from None
    meta = blob.get("pmsr") if isinstance(blob, dict) else None
    refuse_retired(meta, path)
    if isinstance(meta, dict) and meta.get("format") in DETECTION_FORMATS:
        raise CheckpointError(f"{path} is a tracker on detections (kind {DETECTION_FORMATS[meta['format']]} of a "
                              "scenario); this command reads trackers of clean measurement streams")
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a pmsr_nn tracker checkpoint (no 'pmsr' block)")
    if meta.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(f"{path} has checkpoint format {meta.get('format_version')}; "
                              f"this pmsr_nn reads {FORMAT_VERSION}")
    _check_meta(meta, path)
    try:
        cfg = from_dict(ModelConfig, meta["model"], where="checkpoint model")
    except (ConfigError, KeyError) as exc:
        raise CheckpointError(f"{path}: model config unreadable ({exc})") from None
    sd = blob.get("state_dict", {})
    net = {k[len("net."):]: v for k, v in sd.items() if k.startswith("net.")}
    if not net:
        raise CheckpointError(f"{path} holds no network weights")
    for k, v in net.items():
        if not isinstance(v, torch.Tensor):
            raise CheckpointError(f"{path}: weight net.{k} is not a tensor")
        if v.is_floating_point() and not torch.isfinite(v).all():
            raise CheckpointError(f"{path}: weight net.{k} holds NaN or infinite values (a diverged training run?)")
    return meta, cfg, net


def read_blob(path: str | Path, fmt: str, what: str) -> tuple[dict, dict]:
    """``(meta, state_dict)`` of a plain-data checkpoint of format ``fmt`` (``what`` names it in the
    one-line errors), read with ``weights_only=True``; its ``format_version`` must be 1."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise CheckpointError(f"{path} holds objects other than tensors and plain data; refusing to unpickle it") from None
    except (RuntimeError, EOFError, OSError, zipfile.BadZipFile, ValueError, TypeError, KeyError, IndexError,
            AttributeError, UnicodeDecodeError, MemoryError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:120]
        raise CheckpointError(f"{path} is not a readable torch checkpoint (truncated or corrupted?): {first}") from None
    meta = blob.get("pmsr") if isinstance(blob, dict) else None
    refuse_retired(meta, path)
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        found = meta.get("format") if isinstance(meta, dict) else None
        hint = " (a learned tracker of clean streams: use it with kind learned)" if found == FORMAT else ""
        raise CheckpointError(f"{path} is not a {what} checkpoint (format {found!r}){hint}")
    if meta.get("format_version") != 1:
        raise CheckpointError(f"{path} has checkpoint format {meta.get('format_version')}; this pmsr_nn reads 1")
    sd = blob.get("state_dict")
    if not isinstance(sd, dict) or any(not isinstance(v, torch.Tensor) or not torch.isfinite(v).all() for v in sd.values()):
        raise CheckpointError(f"{path}: the network weights are missing, not tensors, or not finite")
    return meta, sd


def save_blob(path: str | Path, meta: dict, state_dict: dict) -> Path:
    """Write ``{'pmsr': meta, 'state_dict': ...}`` atomically (:func:`save_atomically`)."""
    return save_atomically({"pmsr": meta, "state_dict": {k: v.detach().cpu() for k, v in state_dict.items()}}, path)


def save_atomically(obj, path: str | Path, what: str = "checkpoint") -> Path:
    """``torch.save(obj)`` into ``path`` atomically (:func:`write_atomically`), serialised in memory
    first: torch's own file writer reports a full disk as a RuntimeError."""
    import io

    buf = io.BytesIO()
    torch.save(obj, buf)
    return write_atomically(path, buf.getbuffer(), what)


def write_atomically(path: str | Path, data: bytes | memoryview, what: str) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`~pmsr_nn.outputs.atomic_file`: a temporary file
    of ours beside it, synced, then renamed; a temporary name someone else holds is refused, never
    overwritten or removed). A failed write (a full disk: an OSError naming ``path``) leaves the
    earlier file whole and no temporary behind."""
    path = Path(path)
    with atomic_file(path, overwrite=True, what=what) as tmp:
        try:
            tmp.write_bytes(data)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(path)) from None
    return path


def check_detection_sensors(meta: dict, geometry: dict, components, noise_std, dt_s: float, n: int, where: str) -> None:
    """One line naming the first mismatch between the sensors a detection tracker's checkpoint
    (``meta``: geometry, components, noise_std, dt_s, dim_x) was trained for and a scenario's."""
    if meta["geometry"] != geometry:
        raise ConfigError(f"{where}: the checkpoint was trained on another sensor geometry than the scenario's")
    if list(components) != meta["components"]:
        raise ConfigError(f"{where}: the checkpoint reads {meta['components']}, the detections are {list(components)}")
    if n != meta["dim_x"]:
        raise ConfigError(f"{where}: the checkpoint's state has {meta['dim_x']} entries, the scenario's {n}")
    if abs(float(dt_s) - meta["dt_s"]) > 1e-9 * max(1.0, meta["dt_s"]):
        raise ConfigError(f"{where}: the checkpoint was trained at dt = {meta['dt_s']:g} s, the scenario scans "
                          f"every {dt_s:g} s")
    if any(abs(a - b) > 1e-9 * max(abs(b), 1.0) for a, b in zip(noise_std, meta["noise_std"])):
        raise ConfigError(f"{where}: the checkpoint was trained for measurement deviations {meta['noise_std']}, the "
                          f"detections have {[float(v) for v in noise_std]}")
