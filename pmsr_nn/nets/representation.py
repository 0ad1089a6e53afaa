"""What a network reads and what its outputs mean: measurements -> inputs, outputs -> states.

Every learned tracker maps an input sequence ``u (B, K, F)`` to an output sequence
``y (B, K, n)``; the state estimate is ``x = base + scale * y``. Two choices
(:class:`~pmsr_nn.nets.config.ModelConfig` ``inputs`` and ``output``):

``inputs``
    ``measurements`` (the paper): the raw (range, range-rate, azimuth) rows, min-max normalised
    to [-1, 1] over the training split. Over the ~11 km sector a 10 m error is 1e-3 of that
    range, which is what makes precision hard to learn.

    ``local_fixes``: per scan, the state fix's position increment ``p_k - p_{k-1}`` (0 at the
    sequence start), its velocity fix and its absolute position
    (:func:`~pmsr_nn.filters.fixes.state_fixes`), each standardised by its own mean and
    deviation on the training split. Increments and velocities are translation invariant: the
    network learns a local correction, not the geometry; the absolute position only tells it
    where in the sensor geometry (how good the fixes are) it is. Reads one scan before ``k``.

``output``
    ``state`` (the paper): ``base`` is the centre and ``scale`` half the span of the training
    states (min-max normalisation), so ``y`` is the normalised state of Eq. 29.

    ``residual``: ``base`` is the scan's state fix and ``scale`` the deviation of
    ``truth - fix`` per state column on the training split: the network predicts the correction
    to the fix in units of the fix's own error. A zero output reproduces the fix exactly.

The loss is taken on ``y`` (:class:`~pmsr_nn.nets.module.OptimConfig`); errors in SI units are
``scale * (y_pred - y_true)``, whatever the base.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..data.normalise import MinMaxScaler
from ..errors import CheckpointError
from ..filters.fixes import hold_missing_fixes, state_fixes
from ..geometry import Geometry
from ..measurements import MeasurementModel
from .config import ModelConfig

FIX_COMPONENTS = ("range", "range_rate", "azimuth")
MIN_SCALE = 1e-6
"""Smallest residual scale kept (a column the fix gets exactly right, e.g. a level flight's height)."""


def measurement_model(geometry: dict, columns: list[str], dim_x: int) -> MeasurementModel:
    """The measurement model of a dataset or checkpoint (geometry, column names, CA state layout)."""
    from ..motion import ConstantAcceleration

    g = Geometry.from_dict(geometry)
    motion = ConstantAcceleration(spatial_dim=dim_x // 3)
    comps = tuple(dict.fromkeys(c.rsplit("_", 1)[0] for c in columns))
    return MeasurementModel(g, comps, (1.0,) * len(comps), motion.pos_idx, motion.vel_idx)


@dataclass
class Representation:
    """Inputs and outputs of one network (module docstring); statistics fitted on training tracks.

    ``feature_mean`` / ``feature_std`` ``(F,)`` standardise the local features; ``scale (n,)``
    is the residual scale (``output: residual``). The min-max scalers serve the paper's inputs and
    outputs.
    """

    inputs: str
    output: str
    model: MeasurementModel | None  # needed only for fixes
    dim_x: int
    z_scaler: MinMaxScaler
    x_scaler: MinMaxScaler
    feature_mean: torch.Tensor | None = None
    feature_std: torch.Tensor | None = None
    residual_scale: torch.Tensor | None = None
    noise_scale: torch.Tensor | None = None

    _STATS = ("feature_mean", "feature_std", "residual_scale", "noise_scale")

    @property
    def needs_fixes(self) -> bool:
        return self.inputs != "measurements" or self.output == "residual"

    @property
    def extra_context(self) -> int:
        """Scans before ``k`` the inputs at ``k`` read (the increment reads ``k - 1``)."""
        return 1 if self.inputs == "local_fixes" else 0

    def fixes(self, z: torch.Tensor) -> torch.Tensor:
        """State fixes ``(B, K, n)`` of ``z (B, K, m)``, missing ones held from the last valid scan."""
        return hold_missing_fixes(state_fixes(z, self.model, self.dim_x))

    def raw_features(self, fixes: torch.Tensor) -> torch.Tensor:
        """Unstandardised local features ``(B, K, 3d)``: increment, velocity fix, position fix."""
        pos = fixes[..., list(self.model.pos_idx)]
        inc = torch.diff(pos, dim=1, prepend=pos[:, :1])
        return torch.cat([inc, fixes[..., list(self.model.vel_idx)], pos], -1)

    def features(self, z: torch.Tensor, fixes: torch.Tensor | None = None) -> torch.Tensor:
        """Network inputs ``(B, K, F)`` (float64) for measurements ``z (B, K, m)`` in SI units."""
        if self.inputs == "measurements":
            return self.z_scaler.normalise(z.to(torch.float64))
        if self.inputs == "measurements_and_fixes":
            return torch.cat([z.to(torch.float64), self.fixes(z) if fixes is None else fixes], -1)
        f = self.raw_features(self.fixes(z) if fixes is None else fixes)
        return (f - self.feature_mean.to(f)) / self.feature_std.to(f)

    def base(self, z: torch.Tensor, fixes: torch.Tensor | None = None) -> torch.Tensor:
        """``(B, K, n)`` (or ``(n,)`` for ``output: state``), float64."""
        if self.output == "residual":
            return self.fixes(z) if fixes is None else fixes
        return self.x_scaler.lo + 0.5 * self.x_scaler.span

    @property
    def scale(self) -> torch.Tensor:
        """``(n,)``: SI units per unit of network output."""
        return self.residual_scale if self.output == "residual" else 0.5 * self.x_scaler.span

    def targets(self, x: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
        """Network targets ``y`` of states ``x`` (SI) over ``base``, float64."""
        if self.output == "state":  # the scaler's own arithmetic, so the paper's rows stay bit-identical
            return self.x_scaler.normalise(x.to(torch.float64))
        return (x.to(torch.float64) - base) / self.scale.to(torch.float64)

    def states(self, y: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
        """States (SI, float64) of network outputs ``y`` over ``base``."""
        if self.output == "state":
            return self.x_scaler.denormalise(y.to(torch.float64))
        return base + self.scale.to(torch.float64) * y.to(torch.float64)

    def encode(self, z: torch.Tensor, x: torch.Tensor | None = None):
        """``(inputs, targets)`` of whole sequences (targets None without ``x``), float64."""
        s = self.fixes(z) if self.needs_fixes else None
        u = self.features(z, s)
        return u, None if x is None else self.targets(x, self.base(z, s))

    # -- fitting and storage -----------------------------------------------------------------
    @classmethod
    def fit(cls, cfg: ModelConfig, model: MeasurementModel, dim_x: int, z_scaler: MinMaxScaler,
            x_scaler: MinMaxScaler, z: torch.Tensor | None = None, x: torch.Tensor | None = None) -> "Representation":
        """Fit the statistics on training tracks ``z (B, K, m)``, ``x (B, K, n)`` (needed only
        when ``cfg`` uses fixes)."""
        rep = cls(cfg.inputs, cfg.output, model, dim_x, z_scaler, x_scaler)
        if not rep.needs_fixes:
            return rep
        s = rep.fixes(z)
        if rep.inputs == "local_fixes":
            f = rep.raw_features(s).reshape(-1, 3 * (dim_x // 3))
            rep.feature_mean = f.mean(0)
            rep.feature_std = f.std(0).clamp_min(MIN_SCALE)
        if rep.output == "residual":
            rep.residual_scale = (x.to(torch.float64) - s).reshape(-1, dim_x).std(0).clamp_min(MIN_SCALE)
        if rep.inputs == "measurements_and_fixes":  # deviation of each measurement row about the truth
            err = model.residual(z.to(torch.float64), model.h(x.to(torch.float64)))
            rep.noise_scale = err.reshape(-1, err.shape[-1]).std(0).clamp_min(MIN_SCALE)
        return rep

    def to_dict(self) -> dict:
        d = {"inputs": self.inputs, "output": self.output}
        for key in self._STATS:
            v = getattr(self, key)
            if v is not None:
                d[key] = [float(a) for a in v]
        return d

    @classmethod
    def from_meta(cls, meta: dict, cfg: ModelConfig, where: str = "checkpoint") -> "Representation":
        """The representation a checkpoint was trained with (older checkpoints: the paper's)."""
        norm = meta["normalisation"]
        uses_fixes = cfg.inputs != "measurements" or cfg.output == "residual"
        model = measurement_model(meta["geometry"], meta["measurement_columns"], meta["dim_x"]) if uses_fixes else None
        rep = cls(cfg.inputs, cfg.output, model, meta["dim_x"], MinMaxScaler.from_dict(norm["measurements"]),
                  MinMaxScaler.from_dict(norm["states"]))
        stored = norm.get("representation", {})
        if not rep.needs_fixes:
            return rep
        need = {"local_fixes": ("feature_mean", "feature_std"),
                "measurements_and_fixes": ("noise_scale",)}.get(rep.inputs, ()) + \
            (("residual_scale",) if rep.output == "residual" else ())
        size = {"feature_mean": 3 * (meta["dim_x"] // 3), "feature_std": 3 * (meta["dim_x"] // 3),
                "residual_scale": meta["dim_x"], "noise_scale": meta["dim_z"]}
        for key in need:
            v = stored.get(key) if isinstance(stored, dict) else None
            ok = (isinstance(v, list) and len(v) == size[key]
                  and all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in v))
            t = torch.tensor(v, dtype=torch.float64) if ok else None
            if t is None or not bool(torch.isfinite(t).all()) or (key != "feature_mean" and bool((t <= 0).any())):
                raise CheckpointError(f"{where}: the normalisation's representation.{key} is missing or unusable")
            setattr(rep, key, t)
        return rep


def fit_on_training_tracks(model: ModelConfig, dm) -> Representation:
    """The inputs and outputs of ``model``, their statistics fitted on the training tracks of the
    data module ``dm`` (:class:`~pmsr_nn.data.datamodule.TrackWindowDataModule`, its
    normalisation already fitted): what it passes as ``representation``."""
    man = dm.data.manifest
    dim_x = man["shapes"]["states"][2]
    meas = measurement_model(man["geometry"], man["columns"]["measurements"], dim_x)
    z = x = None
    if model.inputs != "measurements" or model.output != "state":
        f, train = dm.data.file, np.sort(dm.tracks["train"])
        z, x = torch.from_numpy(f["measurements"][train]), torch.from_numpy(f["states"][train])
    return Representation.fit(model, meas, dim_x, dm.measurement_scaler, dm.state_scaler, z, x)
