"""The set tracker (:mod:`.set_tracker`) over a whole run, and its checkpoint.

:func:`track_runs` slides the network's window over every scan of every run (all windows of a
block as one batch, in chunks): at scan ``k`` it reads scans ``k - L + 1 .. k`` and answers with
the states it believes exist there. Scans before the first full window get no estimate.
:func:`link_tracks` then labels those per-scan sets as tracks: each estimate continues the track
whose position, carried forward by its velocity over ``dt``, is nearest, if nearer than
``gate_m`` (a Hungarian assignment per scan), and starts a new track otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from .. import __version__
from ..config import from_dict, to_dict
from ..errors import CheckpointError, ConfigError
from ..geometry import Geometry
from ..measurements import MeasurementModel
from .checkpoint import read_blob, save_blob
from .set_tracker import SetTracker, SetTrackerConfig, detection_tokens

FORMAT = "pmsr_nn.set_tracker"


@dataclass
class SetCheckpoint:
    net: SetTracker
    meta: dict
    source: str = ""


def set_metadata(cfg: SetTrackerConfig, model: MeasurementModel, dt_s: float, dim_x: int, **training) -> dict:
    """The plain-data description of a set tracker for ``model``'s detections every ``dt_s`` s."""
    return {"format": FORMAT, "format_version": 1, "pmsr_nn_version": __version__, "model": to_dict(cfg),
            "geometry": model.geometry.to_dict(), "components": list(model.components),
            "noise_std": [float(v) for v in model.noise_std], "pos_idx": list(model.pos_idx),
            "vel_idx": list(model.vel_idx), "dt_s": float(dt_s), "dim_x": int(dim_x), "training": training}


def checkpoint_model(meta: dict) -> MeasurementModel:
    """The measurement model a set checkpoint was trained for (``meta``: geometry, components, ...)."""
    return MeasurementModel(Geometry.from_dict(meta["geometry"]), tuple(meta["components"]),
                            tuple(float(v) for v in meta["noise_std"]), tuple(meta["pos_idx"]),
                            tuple(meta["vel_idx"]), layout="pair")


def save_set_checkpoint(path: str | Path, meta: dict, net: SetTracker) -> Path:
    return save_blob(path, meta, net.state_dict())


def load_set_checkpoint(path: str | Path) -> SetCheckpoint:
    """The checkpoint at ``path``, checked to be ours and whole (one-line errors)."""
    meta, sd = read_blob(path, FORMAT, "set tracker")
    try:
        cfg = from_dict(SetTrackerConfig, meta.get("model"), where="checkpoint model")
        if not isinstance(meta.get("components"), list) or not isinstance(meta.get("noise_std"), list):
            raise KeyError("components")
        model = checkpoint_model(meta)
        dt, dim_x = float(meta["dt_s"]), int(meta["dim_x"])
        if not (dt > 0 and dim_x > max(model.pos_idx + model.vel_idx)):
            raise ValueError(f"dt_s {dt}, dim_x {dim_x}")
    except (ConfigError, KeyError, TypeError, ValueError, IndexError) as exc:
        raise CheckpointError(f"{path}: the checkpoint's description is unreadable ({exc})") from None
    net = SetTracker(cfg, model, dt, dim_x)
    try:
        net.load_state_dict(sd)
    except RuntimeError:
        raise CheckpointError(f"{path}: the network weights do not fit the network the checkpoint describes") from None
    net.eval()
    return SetCheckpoint(net, meta, str(path))


@torch.no_grad()
def track_runs(net: SetTracker, z: torch.Tensor, valid: torch.Tensor, model: MeasurementModel, chunk: int = 256,
               device: str = "cpu") -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per run and scan the network's set: ``pos (B, K, Q, 2)``, ``vel (B, K, Q, 2)`` and existence
    probabilities ``p (B, K, Q)`` (0 at the first ``L - 1`` scans) of detections ``z (B, K, S, M, d)``."""
    B, K, S, M, d = z.shape
    L, Q = net.cfg.window, net.cfg.queries
    pos = z.new_zeros(B, K, Q, 2)
    vel = z.new_zeros(B, K, Q, 2)
    p = z.new_zeros(B, K, Q)
    if K < L:
        return pos, vel, p
    starts = torch.arange(K - L + 1)
    idx = starts[:, None] + torch.arange(L)  # (K', L)
    zw = z[:, idx].reshape(-1, L, S, M, d)  # (B K', L, S, M, d)
    vw = valid[:, idx].reshape(-1, L, S, M)
    out_p, out_v, out_e = [], [], []
    net = net.to(device)
    for i in range(0, zw.shape[0], chunk):
        out = net(detection_tokens(zw[i:i + chunk], vw[i:i + chunk], model, net.cfg).to(device))
        out_p.append(out.pos.double().cpu())
        out_v.append(out.vel.double().cpu())
        out_e.append(torch.sigmoid(out.logit).double().cpu())
    pos[:, L - 1:] = torch.cat(out_p).reshape(B, K - L + 1, Q, 2)
    vel[:, L - 1:] = torch.cat(out_v).reshape(B, K - L + 1, Q, 2)
    p[:, L - 1:] = torch.cat(out_e).reshape(B, K - L + 1, Q)
    return pos, vel, p


def link_tracks(pos: torch.Tensor, vel: torch.Tensor, p: torch.Tensor, dt: float, gate_m: float,
                threshold: float = 0.5) -> tuple[torch.Tensor, torch.Tensor]:
    """Labelled tracks of per-scan sets (module docstring): states ``x (B, K, I, 6)`` in the CA
    layout (acceleration 0) and ``exists (B, K, I)``; ``I`` the most tracks any run started."""
    B, K, Q, _ = pos.shape
    keep = (p >= threshold).numpy()
    P, V = pos.numpy(), vel.numpy()
    ids = np.full((B, K, Q), -1, dtype=np.int64)
    counts = np.zeros(B, dtype=np.int64)
    for b in range(B):
        prev_idx = np.zeros(0, dtype=np.int64)
        prev_ids = np.zeros(0, dtype=np.int64)
        for k in range(K):
            cur = np.flatnonzero(keep[b, k])
            new_ids = np.full(len(cur), -1, dtype=np.int64)
            if len(cur) and len(prev_idx):
                ahead = P[b, k - 1, prev_idx] + V[b, k - 1, prev_idx] * dt
                cost = np.linalg.norm(ahead[:, None, :] - P[b, k, cur][None, :, :], axis=-1)
                r, c = linear_sum_assignment(cost)
                ok = cost[r, c] < gate_m
                new_ids[c[ok]] = prev_ids[r[ok]]
            fresh = new_ids < 0
            new_ids[fresh] = counts[b] + np.arange(int(fresh.sum()))
            counts[b] += int(fresh.sum())
            ids[b, k, cur] = new_ids
            prev_idx, prev_ids = cur, new_ids
    I = int(counts.max()) if B else 0
    x = torch.full((B, K, I, 6), math.nan, dtype=torch.float64)
    exists = torch.zeros(B, K, I, dtype=torch.bool)
    b, k, q = np.nonzero(ids >= 0)
    t = ids[b, k, q]
    x[b, k, t] = torch.from_numpy(np.stack([P[b, k, q, 0], V[b, k, q, 0], np.zeros(len(q)), P[b, k, q, 1],
                                            V[b, k, q, 1], np.zeros(len(q))], -1))
    exists[b, k, t] = True
    return x, exists
