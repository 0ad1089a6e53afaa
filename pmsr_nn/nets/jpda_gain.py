"""The network of the hybrid tracker on detections, and its checkpoint.

:class:`GainNet` is the learned gain correction that :class:`~pmsr_nn.trackers.learned_gain.GainCorrection`
calls per track and sensor (what it reads and why is said there). Its checkpoint
(:func:`save_gain_checkpoint`, :func:`load_gain_checkpoint`) is self-contained plain data plus
weights, read with ``torch.load(weights_only=True)`` (nothing is unpickled): the sensors it was
trained for (geometry, measurement components and their deviations, interval), the state and
measurement scales and the network's size. :func:`check_gain_compatible` refuses, in one line, a
scenario whose sensors differ.
"""

from __future__ import annotations

import math
import os
import pickle
import zipfile
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from .. import __version__
from ..errors import CheckpointError, ConfigError

FORMAT = "pmsr_nn.jpda_gain"
FORMAT_VERSION = 1


class GainNet(nn.Module):
    """``(features (R, 2d + 1 + S), memory (R, H)) -> (G (R, n, d), memory (R, H))``: one GRU step per
    track and sensor. The output layer starts at zero (the untrained hybrid is S-MSJPDA) and is
    scaled by ``gain_scale``."""

    def __init__(self, n_pairs: int, d: int, n: int, hidden: int = 32, gain_scale: float = 0.1):
        super().__init__()
        self.n_pairs, self.d, self.n, self.hidden_size, self.gain_scale = n_pairs, d, n, hidden, gain_scale
        self.inp = nn.Sequential(nn.Linear(2 * d + 1 + n_pairs, hidden), nn.ReLU())
        self.gru = nn.GRUCell(hidden, hidden)
        self.out = nn.Linear(hidden, n * d)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, features: torch.Tensor, memory: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        memory = self.gru(self.inp(features), memory)
        return self.out(memory).view(-1, self.n, self.d) * self.gain_scale, memory


@dataclass
class GainCheckpoint:
    """A loaded checkpoint: the network (eval mode), its scales ``s_z (d,)`` and ``s_x (n,)`` (SI)
    and the plain-data ``meta`` block."""

    net: GainNet
    s_z: torch.Tensor
    s_x: torch.Tensor
    meta: dict
    source: str = ""


def gain_metadata(geometry: dict, components: list[str], noise_std: list[float], dt_s: float, net: GainNet,
                  s_x: list[float], **training) -> dict:
    """The plain-data block of a checkpoint (``training``: free-form facts: seed, steps, config)."""
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "pmsr_nn_version": __version__,
            "geometry": geometry, "components": list(components), "noise_std": [float(v) for v in noise_std],
            "dt_s": float(dt_s), "n_pairs": net.n_pairs, "dim_x": net.n, "hidden": net.hidden_size,
            "gain_scale": float(net.gain_scale), "state_scale": [float(v) for v in s_x], "training": training}


def save_gain_checkpoint(path: str | Path, meta: dict, net: GainNet) -> Path:
    """Write ``{'pmsr': meta, 'state_dict': ...}`` atomically (temporary file, then rename)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        torch.save({"pmsr": meta, "state_dict": {k: v.detach().cpu() for k, v in net.state_dict().items()}}, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


_META = {"geometry": dict, "components": list, "noise_std": list, "dt_s": (int, float), "n_pairs": int, "dim_x": int,
         "hidden": int, "gain_scale": (int, float), "state_scale": list}


def load_gain_checkpoint(path: str | Path) -> GainCheckpoint:
    """The checkpoint at ``path``, checked to be ours and whole (one-line :class:`CheckpointError` otherwise)."""
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
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        what = meta.get("format") if isinstance(meta, dict) else None
        hint = " (a learned tracker of clean streams: use it with kind learned)" if what == "pmsr_nn.tracker" else ""
        raise CheckpointError(f"{path} is not a learned-gain JPDA checkpoint (format {what!r}){hint}")
    if meta.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(f"{path} has checkpoint format {meta.get('format_version')}; this pmsr_nn reads "
                              f"{FORMAT_VERSION}")
    for key, kind in _META.items():
        if not isinstance(meta.get(key), kind) or isinstance(meta.get(key), bool):
            raise CheckpointError(f"{path}: the checkpoint's '{key}' is missing or of the wrong kind (edited or corrupted?)")
    d, n = len(meta["components"]), meta["dim_x"]
    scales = meta["noise_std"] + meta["state_scale"]
    if (len(meta["noise_std"]) != d or len(meta["state_scale"]) != n or meta["n_pairs"] < 1 or meta["hidden"] < 1
            or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in scales)):
        raise CheckpointError(f"{path}: the checkpoint's scales or sizes are inconsistent or not positive")
    net = GainNet(meta["n_pairs"], d, n, meta["hidden"], float(meta["gain_scale"]))
    sd = blob.get("state_dict")
    if not isinstance(sd, dict) or any(not isinstance(v, torch.Tensor) or not torch.isfinite(v).all() for v in sd.values()):
        raise CheckpointError(f"{path}: the network weights are missing, not tensors, or not finite")
    try:
        net.load_state_dict(sd)
    except RuntimeError:
        raise CheckpointError(f"{path}: the network weights do not fit the network the checkpoint describes") from None
    net.eval()
    return GainCheckpoint(net, torch.tensor(meta["noise_std"], dtype=torch.float64),
                          torch.tensor(meta["state_scale"], dtype=torch.float64), meta, str(path))


def check_gain_compatible(ck: GainCheckpoint, geometry: dict, components, noise_std, dt_s: float, n: int,
                          where: str) -> None:
    """One line naming the first mismatch between the checkpoint's sensors and a scenario's."""
    meta = ck.meta
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
