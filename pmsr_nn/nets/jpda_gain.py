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
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from .. import __version__
from ..errors import CheckpointError, ConfigError
from .checkpoint import check_detection_sensors, read_blob, save_blob

FORMAT = "pmsr_nn.jpda_gain"
FORMAT_VERSION = 1


class GainNet(nn.Module):
    """``(features (R, F), memory (R, H)) -> (G (R, n, d), scale (R,), memory (R, H))``: one GRU step
    per track and sensor (``F``: :func:`~pmsr_nn.trackers.learned_gain.feature_count`). The
    output layer starts at zero (the untrained hybrid is S-MSJPDA); ``G`` is scaled by
    ``gain_scale``, ``scale = tanh(.)``."""

    def __init__(self, n_pairs: int, d: int, n: int, hidden: int = 32, gain_scale: float = 0.1):
        super().__init__()
        from ..trackers.learned_gain import feature_count

        self.n_pairs, self.d, self.n, self.hidden_size, self.gain_scale = n_pairs, d, n, hidden, gain_scale
        self.inp = nn.Sequential(nn.Linear(feature_count(d, n_pairs), hidden), nn.ReLU())
        self.gru = nn.GRUCell(hidden, hidden)
        self.out = nn.Linear(hidden, n * d + 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, features: torch.Tensor, memory: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        memory = self.gru(self.inp(features), memory)
        y = self.out(memory)
        return y[:, :-1].view(-1, self.n, self.d) * self.gain_scale, torch.tanh(y[:, -1]), memory


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
    """Write the checkpoint atomically (temporary file, then rename)."""
    return save_blob(path, meta, net.state_dict())


_META = {"geometry": dict, "components": list, "noise_std": list, "dt_s": (int, float), "n_pairs": int, "dim_x": int,
         "hidden": int, "gain_scale": (int, float), "state_scale": list}


def load_gain_checkpoint(path: str | Path) -> GainCheckpoint:
    """The checkpoint at ``path``, checked to be ours and whole (one-line :class:`CheckpointError` otherwise)."""
    meta, sd = read_blob(path, FORMAT, "learned-gain JPDA")
    for key, kind in _META.items():
        if not isinstance(meta.get(key), kind) or isinstance(meta.get(key), bool):
            raise CheckpointError(f"{path}: the checkpoint's '{key}' is missing or of the wrong kind (edited or corrupted?)")
    d, n = len(meta["components"]), meta["dim_x"]
    scales = meta["noise_std"] + meta["state_scale"]
    if (len(meta["noise_std"]) != d or len(meta["state_scale"]) != n or meta["n_pairs"] < 1 or meta["hidden"] < 1
            or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in scales)):
        raise CheckpointError(f"{path}: the checkpoint's scales or sizes are inconsistent or not positive")
    net = GainNet(meta["n_pairs"], d, n, meta["hidden"], float(meta["gain_scale"]))
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
    check_detection_sensors(ck.meta, geometry, components, noise_std, dt_s, n, where)
