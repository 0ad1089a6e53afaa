"""Linear kinematic motion models: constant velocity (CV) and constant acceleration (CA).

State layout is axis-major: CV ``[x, vx, y, vy]`` (3-D adds ``z, vz``), CA
``[x, vx, ax, y, vy, ay]`` (3-D adds ``z, vz, az``). Every model is a chain of integrators per
axis, so ``F(dt)`` is block-diagonal with the per-axis block ``exp(S dt)`` (``S`` the shift matrix).

Process noise
-------------
* CV: the discrete white-noise acceleration model of the S-MSJPDA paper (and the SMC-PHD paper),
  per axis ``q * [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]`` with ``q`` the acceleration variance in m^2/s^4.
  Its ``Q`` has rank one per axis (one acceleration per interval).
* CV continuous (``cv_continuous``): continuous white-noise acceleration of power spectral density
  ``q`` in m^2/s^3 (the PMHT paper's "process noise intensity"), per axis
  ``q * [[dt^3/3, dt^2/2], [dt^2/2, dt]]``: full rank, so a trajectory has a finite prior density.
* CA: Eq. 12 of the MDFNN paper (continuous white-noise jerk), per axis
  ``q * [[dt^5/20, dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]]`` with ``q`` the
  power spectral density in m^2/s^5.

``q`` may be a scalar, a per-run tensor ``(...,)`` or a per-axis tensor ``(..., spatial_dim)``
(e.g. zero vertical noise for a target that keeps its altitude).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .errors import ConfigError
from .rng import standard_normal


@dataclass(frozen=True)
class KinematicModel:
    """A chain of ``order`` integrators per spatial axis (order 2: CV, order 3: CA)."""

    spatial_dim: int = 2

    order: int = field(default=0, init=False)  # integrators per axis, set by each subclass
    name: str = field(default="", init=False)

    def __post_init__(self) -> None:
        if self.spatial_dim not in (2, 3):
            raise ConfigError(f"spatial_dim must be 2 or 3, got {self.spatial_dim}")

    @property
    def dim_x(self) -> int:
        return self.spatial_dim * self.order

    @property
    def pos_idx(self) -> tuple[int, ...]:
        return tuple(a * self.order for a in range(self.spatial_dim))

    @property
    def vel_idx(self) -> tuple[int, ...]:
        return tuple(a * self.order + 1 for a in range(self.spatial_dim))

    @property
    def acc_idx(self) -> tuple[int, ...]:
        if self.order < 3:
            raise AttributeError(f"{self.name} has no acceleration states")
        return tuple(a * self.order + 2 for a in range(self.spatial_dim))

    def F_block(self, dt, dtype=torch.float64, device=None) -> torch.Tensor:
        """Per-axis transition ``(..., order, order)``: entry ``(i, j) = dt^(j-i) / (j-i)!`` for
        ``j >= i``; ``dt`` a float or a tensor of intervals ``(...,)`` (s)."""
        n = self.order
        dt = torch.as_tensor(dt, dtype=dtype, device=device)
        blk = torch.zeros(*dt.shape, n, n, dtype=dtype, device=device)
        for i in range(n):
            for j in range(i, n):
                blk[..., i, j] = dt ** (j - i) / math.factorial(j - i)
        return blk

    def Q_block(self, dt: float, dtype=torch.float64, device=None) -> torch.Tensor:
        """Per-axis process-noise covariance for unit ``q``, ``(order, order)``."""
        raise NotImplementedError

    def F(self, dt, dtype=torch.float64, device=None) -> torch.Tensor:
        """State transition ``(dim_x, dim_x)`` over an interval ``dt`` (s), or ``(..., dim_x, dim_x)``
        for a tensor of intervals ``dt (...,)``."""
        blk = self.F_block(dt, dtype, device)
        eye = torch.eye(self.spatial_dim, dtype=dtype, device=device)
        return torch.einsum("ab,...ij->...aibj", eye, blk).reshape(*blk.shape[:-2], self.dim_x, self.dim_x)

    def _per_axis_q(self, q, dtype, device) -> torch.Tensor:
        q = torch.as_tensor(q, dtype=dtype, device=device)
        if q.dim() == 0 or q.shape[-1] != self.spatial_dim:
            q = q.unsqueeze(-1).expand(*q.shape, self.spatial_dim)
        if bool((q < 0).any()) or not bool(torch.isfinite(q).all()):
            raise ConfigError("process noise intensity q must be finite and non-negative")
        return q

    def _block_diag(self, per_axis: torch.Tensor, blk: torch.Tensor) -> torch.Tensor:
        """``per_axis (..., D)`` and ``blk (n, n)`` -> ``kron(diag(per_axis), blk)`` ``(..., D*n, D*n)``."""
        D, n = self.spatial_dim, self.order
        eye = torch.eye(D, dtype=blk.dtype, device=blk.device)
        out = per_axis[..., :, None, None, None] * eye[:, None, :, None] * blk[None, :, None, :]
        return out.reshape(*per_axis.shape[:-1], D * n, D * n)

    def Q(self, dt: float, q, dtype=torch.float64, device=None) -> torch.Tensor:
        """Process-noise covariance ``(..., dim_x, dim_x)``; ``q`` scalar, ``(...,)`` or ``(..., spatial_dim)``."""
        return self._block_diag(self._per_axis_q(q, dtype, device), self.Q_block(dt, dtype, device))

    def noise_factor(self, dt: float, q, dtype=torch.float64, device=None) -> torch.Tensor:
        """A square root ``L`` with ``L L^T = Q(dt, q)``, valid for ``q = 0`` on some axes."""
        blk = torch.linalg.cholesky(self.Q_block(dt, dtype, device))
        return self._block_diag(self._per_axis_q(q, dtype, device).sqrt(), blk)

    def propagate(self, x0: torch.Tensor, increments: torch.Tensor, dt: float) -> torch.Tensor:
        """Run ``x_k = F x_{k-1} + w_k`` for all runs at once.

        ``x0 (B, dim_x)``, ``increments (B, K-1, dim_x)`` (the ``w_k``) -> states ``(B, K, dim_x)``
        with ``x_0`` first. Instead of K matrix products, each derivative of the chain is a
        cumulative sum over time of the already-known higher derivatives (exact for ``exp(S dt)``).
        """
        B, steps = x0.shape[0], increments.shape[1] + 1
        n = self.order
        w = increments.reshape(B, steps - 1, self.spatial_dim, n)
        start = x0.reshape(B, 1, self.spatial_dim, n)
        out = torch.empty(B, steps, self.spatial_dim, n, dtype=x0.dtype, device=x0.device)
        for c in reversed(range(n)):  # highest derivative first
            step = w[..., c].clone()
            for m in range(1, n - c):
                step += (dt**m / math.factorial(m)) * out[:, :-1, :, c + m]
            out[:, :1, :, c] = start[..., c]
            out[:, 1:, :, c] = start[..., c] + torch.cumsum(step, dim=1)
        return out.reshape(B, steps, self.dim_x)

    def sample(self, x0: torch.Tensor, steps: int, dt: float, q, generator: torch.Generator | None = None) -> torch.Tensor:
        """Draw trajectories ``(B, steps, dim_x)`` starting at ``x0 (B, dim_x)``; ``q`` as in :meth:`Q`."""
        L = self.noise_factor(dt, q, x0.dtype, x0.device)  # (dim_x, dim_x) or (B, dim_x, dim_x)
        n = standard_normal((x0.shape[0], steps - 1, self.dim_x), generator, x0.dtype, x0.device)
        if L.dim() == 2:
            w = n @ L.T
        else:
            w = torch.einsum("bij,bkj->bki", L, n)
        return self.propagate(x0, w, dt)


@dataclass(frozen=True)
class ConstantVelocity(KinematicModel):
    """CV model; ``q`` is the white acceleration variance (m^2/s^4)."""

    order: int = field(default=2, init=False)
    name: str = field(default="cv", init=False)

    def Q_block(self, dt: float, dtype=torch.float64, device=None) -> torch.Tensor:
        return torch.tensor([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]], dtype=dtype, device=device)

    def noise_factor(self, dt: float, q, dtype=torch.float64, device=None) -> torch.Tensor:
        # The CV block is rank one (noise enters through one acceleration): L = sqrt(q) [dt^2/2, dt]^T.
        blk = torch.tensor([[dt**2 / 2, 0.0], [dt, 0.0]], dtype=dtype, device=device)
        return self._block_diag(self._per_axis_q(q, dtype, device).sqrt(), blk)


@dataclass(frozen=True)
class ContinuousConstantVelocity(ConstantVelocity):
    """CV model driven by continuous white acceleration; ``q`` is its PSD (m^2/s^3)."""

    name: str = field(default="cv_continuous", init=False)

    def Q_block(self, dt: float, dtype=torch.float64, device=None) -> torch.Tensor:
        return torch.tensor([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]], dtype=dtype, device=device)

    def noise_factor(self, dt: float, q, dtype=torch.float64, device=None) -> torch.Tensor:
        return KinematicModel.noise_factor(self, dt, q, dtype, device)


@dataclass(frozen=True)
class ConstantAcceleration(KinematicModel):
    """CA model (Eq. 12 of the MDFNN paper); ``q`` is the jerk power spectral density (m^2/s^5)."""

    order: int = field(default=3, init=False)
    name: str = field(default="ca", init=False)

    def Q_block(self, dt: float, dtype=torch.float64, device=None) -> torch.Tensor:
        return torch.tensor(
            [
                [dt**5 / 20, dt**4 / 8, dt**3 / 6],
                [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                [dt**3 / 6, dt**2 / 2, dt],
            ],
            dtype=dtype,
            device=device,
        )


def motion_model(name: str, spatial_dim: int = 2) -> KinematicModel:
    """``"cv"``, ``"cv_continuous"`` or ``"ca"`` -> the model instance."""
    models = {"cv": ConstantVelocity, "cv_continuous": ContinuousConstantVelocity, "ca": ConstantAcceleration}
    if name not in models:
        raise ConfigError(f"unknown motion model {name!r}; choose one of {sorted(models)}")
    return models[name](spatial_dim=spatial_dim)
