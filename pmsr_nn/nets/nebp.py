"""The graph network of neural-enhanced BP (NEBP, :mod:`pmsr_nn.trackers.message_refiner`) and its
checkpoint.

:class:`NEBPNet` reads one list's association graph (:class:`~pmsr_nn.trackers.message_refiner.Graph`):
edge, detection and track-node features are embedded, then ``rounds`` rounds of message passing
over the bipartite graph (each node sums its edges' embeddings; each edge reads its two nodes)
refine them; two heads give each gated edge's log-correction of its likelihood ratio and each
detection's log-correction of its new-target weight, bounded to ``bound`` nats. The heads start
at zero: the untrained NEBP is BP.

The checkpoint (:func:`save_nebp_checkpoint`, :func:`load_nebp_checkpoint`) is plain data plus
weights, read with ``torch.load(weights_only=True)``: the sensors it was trained for (geometry,
pair count, measurement components and deviations, interval, state size), the measurement scales
of its features and the network's size. :func:`check_nebp_compatible` refuses, in one line, a
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
from ..trackers.message_refiner import EDGE_EXTRA, TRACK_FEATURES, Graph, bounded, detection_feature_count
from .checkpoint import check_detection_sensors, read_blob, save_blob

FORMAT = "pmsr_nn.nebp"
FORMAT_VERSION = 1


def _mlp(n_in: int, hidden: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())


class NEBPNet(nn.Module):
    """``Graph -> (edge_log (E,), det_log (D,))`` (module docstring), in the parameters' dtype."""

    def __init__(self, n_pairs: int, components, hidden: int = 32, rounds: int = 2, bound: float = 4.0):
        super().__init__()
        self.n_pairs, self.components = n_pairs, tuple(components)
        self.hidden_size, self.rounds, self.bound = hidden, rounds, float(bound)
        d = len(self.components)
        fe, fd, ft = d + EDGE_EXTRA, detection_feature_count(self.components, n_pairs), TRACK_FEATURES
        self.edge_in = _mlp(fe + fd + ft, hidden)
        self.det_in = _mlp(fd, hidden)
        self.track_in = _mlp(ft, hidden)
        self.det_up = nn.ModuleList(_mlp(2 * hidden, hidden) for _ in range(rounds))
        self.track_up = nn.ModuleList(_mlp(2 * hidden, hidden) for _ in range(rounds))
        self.edge_up = nn.ModuleList(_mlp(3 * hidden, hidden) for _ in range(rounds))
        self.edge_out = nn.Linear(hidden, 1)
        self.det_out = nn.Linear(2 * hidden, 1)
        for head in (self.edge_out, self.det_out):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)

    def forward(self, graph: Graph) -> tuple[torch.Tensor, torch.Tensor]:
        ed, et = graph.edge_det, graph.edge_track
        D, T, H = graph.det_x.shape[0], graph.track_x.shape[0], self.hidden_size
        dt = self.edge_out.weight.dtype
        fe, fd, ft = graph.edge_x.to(dt), graph.det_x.to(dt), graph.track_x.to(dt)
        hd, ht = self.det_in(fd), self.track_in(ft)
        he = self.edge_in(torch.cat([fe, fd[ed], ft[et]], -1))
        agg_d = hd.new_zeros(D, H)
        for r in range(self.rounds):
            agg_d = hd.new_zeros(D, H).index_add(0, ed, he)
            agg_t = ht.new_zeros(T, H).index_add(0, et, he)
            hd = hd + self.det_up[r](torch.cat([hd, agg_d], -1))
            ht = ht + self.track_up[r](torch.cat([ht, agg_t], -1))
            he = he + self.edge_up[r](torch.cat([he, hd[ed], ht[et]], -1))
        edge_log = bounded(self.edge_out(he)[:, 0], self.bound)
        det_log = bounded(self.det_out(torch.cat([hd, agg_d], -1))[:, 0], self.bound)
        return edge_log, det_log


@dataclass
class NEBPCheckpoint:
    """A loaded checkpoint: the network (eval mode), its measurement scales ``scales (d,)`` and the
    plain-data ``meta`` block."""

    net: NEBPNet
    scales: torch.Tensor
    meta: dict
    source: str = ""


def nebp_metadata(geometry: dict, components: list[str], noise_std: list[float], dt_s: float, dim_x: int,
                  net: NEBPNet, scales: list[float], **training) -> dict:
    """The plain-data block of a checkpoint (``training``: free-form facts: seed, steps, config)."""
    return {"format": FORMAT, "format_version": FORMAT_VERSION, "pmsr_nn_version": __version__,
            "geometry": geometry, "components": list(components), "noise_std": [float(v) for v in noise_std],
            "dt_s": float(dt_s), "dim_x": int(dim_x), "n_pairs": net.n_pairs, "hidden": net.hidden_size,
            "rounds": net.rounds, "bound": net.bound, "scales": [float(v) for v in scales], "training": training}


def save_nebp_checkpoint(path: str | Path, meta: dict, net: NEBPNet) -> Path:
    """Write the checkpoint atomically (temporary file, then rename)."""
    return save_blob(path, meta, net.state_dict())


_META = {"geometry": dict, "components": list, "noise_std": list, "dt_s": (int, float), "dim_x": int, "n_pairs": int,
         "hidden": int, "rounds": int, "bound": (int, float), "scales": list}


def load_nebp_checkpoint(path: str | Path) -> NEBPCheckpoint:
    """The checkpoint at ``path``, checked to be ours and whole (one-line :class:`CheckpointError` otherwise)."""
    meta, sd = read_blob(path, FORMAT, "NEBP")
    for key, kind in _META.items():
        if not isinstance(meta.get(key), kind) or isinstance(meta.get(key), bool):
            raise CheckpointError(f"{path}: the checkpoint's '{key}' is missing or of the wrong kind (edited or corrupted?)")
    d = len(meta["components"])
    numbers = meta["noise_std"] + meta["scales"] + [meta["bound"]]
    if (len(meta["noise_std"]) != d or len(meta["scales"]) != d or meta["n_pairs"] < 1 or meta["hidden"] < 1
            or meta["rounds"] < 0 or not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in numbers)):
        raise CheckpointError(f"{path}: the checkpoint's scales or sizes are inconsistent or not positive")
    net = NEBPNet(meta["n_pairs"], meta["components"], meta["hidden"], meta["rounds"], float(meta["bound"]))
    try:
        net.load_state_dict(sd)
    except RuntimeError:
        raise CheckpointError(f"{path}: the network weights do not fit the network the checkpoint describes") from None
    net.eval()
    return NEBPCheckpoint(net, torch.tensor(meta["scales"], dtype=torch.float64), meta, str(path))


def check_nebp_compatible(ck: NEBPCheckpoint, geometry: dict, n_pairs: int, components, noise_std, dt_s: float,
                          n: int, where: str) -> None:
    """One line naming the first mismatch between the checkpoint's sensors and a scenario's: the
    pair count and the measurement set first (what the network's inputs are), then the rest."""
    if n_pairs != ck.meta["n_pairs"]:
        raise ConfigError(f"{where}: the checkpoint was trained for {ck.meta['n_pairs']} transmitter-receiver pairs, "
                          f"the scenario has {n_pairs}")
    if list(components) != ck.meta["components"]:
        raise ConfigError(f"{where}: the checkpoint reads {ck.meta['components']}, the detections are {list(components)}")
    check_detection_sensors(ck.meta, geometry, components, noise_std, dt_s, n, where)
