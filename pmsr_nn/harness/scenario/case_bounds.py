"""The information bounds of a case whose runs all fly the same flights (part of preparing it).

Takes the true states ``x (K, N, n)`` (NaN where a target is not alive), ``alive (K, N)``, the
shared :class:`~pmsr_nn.methods.Models` and the initiation prior ``P0 (n, n)``; gives per target,
from its birth, the per-trajectory PCRB curves (:func:`case_bounds`, a :class:`~.prepared.Bounds`)
and the finite-memory bound of each causal learned tracker (:func:`memory_bounds`), each a
``(K, N)`` numpy curve in metres (or metres per second), NaN where a target is not alive; and the
bound of a case's range-Doppler maps (:func:`maps_bound`).
"""

from __future__ import annotations

import numpy as np
import torch

from ...bounds import finite_memory_pcrb, pcrb
from ...methods import Models, method_kind
from ...tbd.bound import map_bound
from ...tbd.scene import MapScene
from .prepared import Bounds


def _per_target(x: torch.Tensor, alive: torch.Tensor, fn) -> list[tuple[int, int, object]]:
    """``fn(truth (1, L, n), first)`` for each target over its life from scan ``first``:
    ``[(first, end, result), ...]``."""
    out = []
    for t in range(alive.shape[1]):
        on = torch.nonzero(alive[:, t]).flatten()
        k0, k1 = int(on[0]), int(on[-1]) + 1
        out.append((k0, k1, fn(x[k0:k1, t][None], k0)))
    return out


def _curves(parts, K: int, get) -> np.ndarray:
    """``(K, N)`` from per-target curves ``get(result) (L,)`` placed at their lives (NaN elsewhere)."""
    out = np.full((K, len(parts)), np.nan)
    for t, (k0, k1, r) in enumerate(parts):
        out[k0:k1, t] = get(r)
    return out


def case_bounds(x: torch.Tensor, alive: torch.Tensor, models: Models, P0: torch.Tensor) -> Bounds:
    """Per-trajectory PCRB of each target over its life (:class:`~.prepared.Bounds`)."""
    m = models
    full = _per_target(x, alive, lambda tr, _: pcrb(tr, m.motion, m.dt, m.q, m.model, m.R, P0))
    q0 = _per_target(x, alive, lambda tr, _: pcrb(tr, m.motion, m.dt, 0.0, m.model, m.R, P0))
    K = alive.shape[0]
    return Bounds(_curves(full, K, lambda b: b.position_rmse().numpy()), _curves(full, K, lambda b: b.velocity_rmse().numpy()),
                  _curves(full, K, lambda b: b.position_rmse("smoothing").numpy()),
                  _curves(full, K, lambda b: b.velocity_rmse("smoothing").numpy()),
                  _curves(q0, K, lambda b: b.position_rmse().numpy()),
                  _curves(q0, K, lambda b: b.position_rmse("smoothing").numpy()))


def memory_bounds(x: torch.Tensor, alive: torch.Tensor, methods, resources: dict, causal: dict[str, bool],
                  models: Models) -> dict[str, tuple[int, np.ndarray]]:
    """Per causal learned method, the filtering bound of only the scans its estimates read
    (:meth:`Tracker.memory` at the method's stride; every scan for whole-sequence inference) with
    the training states' spread as prior: no
    network of that shape can beat it, whatever its training. Returns ``name -> (scans read,
    (K, N) curve)``; methods that share both share one computation."""
    out, cache = {}, {}
    m = models
    for spec in methods:
        kind = method_kind(spec.kind)
        if not (kind.needs_checkpoint and kind.reads == "measurements") or not causal[spec.name]:
            continue
        t = resources[spec.name]
        stride = spec.option("stride")
        whole = "inference" in kind.options and spec.option("inference") == "whole_sequence"
        L = alive.shape[0] if whole else t.memory(None if stride is None else int(stride))
        P0 = t.training_spread()
        key = (L, tuple(torch.diagonal(P0).tolist()))
        if key not in cache:
            parts = _per_target(x, alive, lambda tr, _: finite_memory_pcrb(tr, m.motion, m.dt, m.q, m.model, m.R, P0,
                                                                       memory=min(L, tr.shape[1])))
            cache[key] = min(L, alive.shape[0]), _curves(parts, alive.shape[0], lambda b: b.position_rmse().numpy())
        out[spec.name] = cache[key]
    return out


def maps_bound(scene: MapScene, x: torch.Tensor, alive: torch.Tensor, models: Models, prior_sd: torch.Tensor) -> np.ndarray:
    """The filtering bound of each target seen through the case's maps alone
    (:func:`~pmsr_nn.tbd.bound.map_bound`: every map's information and the model's ``q`` from its
    birth), as the position RMSE over the targets living at each frame ``(K,)`` (m; NaN where
    none lives): what the map rows' RMS error is held to. The prior is what the map filters know
    at a birth, the birth box (uniform: variance ``width^2 / 12`` of position and velocity), and
    ``prior_sd (n,)`` for the state's other components."""
    m = models
    lo, hi = scene.birth_box.bounds()
    var = prior_sd.to(torch.float64).clone() ** 2
    var[list(scene.state_index)] = (hi - lo) ** 2 / 12
    P0 = torch.diag(var)
    parts = _per_target(x, alive, lambda tr, first: map_bound(scene, tr[0], first, m.motion, m.dt, m.q, P0))
    per_target = _curves(parts, alive.shape[0], lambda b: b.position_rmse().numpy())
    living = np.isfinite(per_target).sum(1)
    mse = np.where(living > 0, np.nansum(per_target ** 2, axis=1) / np.maximum(living, 1), np.nan)
    return np.sqrt(mse)
