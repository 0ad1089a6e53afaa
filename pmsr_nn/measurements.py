"""Bistatic measurement functions, their analytic Jacobians, and composed measurement models.

All functions are batched torch: a target position ``pos`` is ``(..., d)`` (d = 2 or 3), the
sensor positions of the pairs are ``(N, d)``, and a per-pair output is ``(..., N)``. Units are
SI (m, m/s, rad); Doppler (Hz) and delay (s) are converted at this boundary only.

Conventions
-----------
* Bistatic range ``r = |p - tx| + |p - rx|`` (m).
* Bistatic range-rate ``rdot = dr/dt = v . (u_tx + u_rx)`` with ``u_s = (p - s) / |p - s|``:
  positive for a receding target. (Eq. 5 of the MDFNN paper writes ``(s - p)/|s - p|``, i.e. the
  opposite sign; only the sign convention differs.)
* Doppler ``f_d = -rdot * f_c / c`` (Hz), the sign of Eq. 3 in the S-MSJPDA paper: an
  approaching target has a positive Doppler shift.
* Delay ``tau = r / c`` (s).
* Azimuth at the receiver, clockwise from north: ``atan2(x - x_rx, y - y_rx)`` in (-pi, pi],
  using the horizontal coordinates only. (Eq. 5 of the MDFNN paper writes the transmitter's
  coordinates; the receiver measures the angle, so we use the receiver's.)

Targets on top of a sensor
--------------------------
The unit vector ``u_s`` (and so the range-rate and every Jacobian) is undefined when the target
sits on a sensor. We never return NaN: distances are guarded from below by
``MIN_SENSOR_DISTANCE_M`` (a target exactly on a sensor gets ``u_s = 0``, finite Jacobians), and
:meth:`MeasurementModel.near_sensor` flags states closer than a chosen radius so that a simulator
can reject them and a filter can report them. The guard only acts below 1 mm, where no physical
radar measures anything.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Sequence

import torch

from . import SPEED_OF_LIGHT
from .errors import ConfigError
from .geometry import Geometry
from .rng import standard_normal

MIN_SENSOR_DISTANCE_M = 1e-3

COMPONENTS = ("range", "range_rate", "doppler", "delay", "azimuth")
"""Measurement kinds a model can be composed of. Units: m, m/s, Hz, s, rad."""


def wrap_angle(a: torch.Tensor) -> torch.Tensor:
    """Wrap angles (rad) to (-pi, pi]."""
    return math.pi - torch.remainder(math.pi - a, 2 * math.pi)


def _offsets(pos: torch.Tensor, sensors: torch.Tensor):
    """Offsets ``p - s`` ``(..., N, d)``, guarded distances ``(..., N)`` and unit vectors ``(..., N, d)``."""
    diff = pos.unsqueeze(-2) - sensors
    dist = torch.linalg.vector_norm(diff, dim=-1).clamp_min(MIN_SENSOR_DISTANCE_M)
    return diff, dist, diff / dist.unsqueeze(-1)


def bistatic_range(pos: torch.Tensor, tx: torch.Tensor, rx: torch.Tensor) -> torch.Tensor:
    """Bistatic range ``|p - tx| + |p - rx|`` in m: ``pos (..., d)``, ``tx, rx (N, d)`` -> ``(..., N)``."""
    return _offsets(pos, tx)[1] + _offsets(pos, rx)[1]


def bistatic_range_rate(pos: torch.Tensor, vel: torch.Tensor, tx: torch.Tensor, rx: torch.Tensor) -> torch.Tensor:
    """Bistatic range-rate ``v . (u_tx + u_rx)`` in m/s, ``(..., N)``."""
    unit_sum = _offsets(pos, tx)[2] + _offsets(pos, rx)[2]
    return (unit_sum * vel.unsqueeze(-2)).sum(-1)


def doppler_hz(pos: torch.Tensor, vel: torch.Tensor, tx: torch.Tensor, rx: torch.Tensor, carrier_hz: torch.Tensor) -> torch.Tensor:
    """Bistatic Doppler ``-rdot * f_c / c`` in Hz, ``(..., N)``; ``carrier_hz`` is ``(N,)``."""
    return -bistatic_range_rate(pos, vel, tx, rx) * carrier_hz / SPEED_OF_LIGHT


def bistatic_delay_s(pos: torch.Tensor, tx: torch.Tensor, rx: torch.Tensor) -> torch.Tensor:
    """Bistatic delay ``r / c`` in s, ``(..., N)``."""
    return bistatic_range(pos, tx, rx) / SPEED_OF_LIGHT


def azimuth(pos: torch.Tensor, rx: torch.Tensor) -> torch.Tensor:
    """Azimuth at the receiver, clockwise from north, in (-pi, pi] rad, ``(..., N)``."""
    dx = pos[..., None, 0] - rx[:, 0]
    dy = pos[..., None, 1] - rx[:, 1]
    return torch.atan2(dx, dy)


@functools.lru_cache(maxsize=64)
def _sensor_tensors(g: Geometry, dtype, device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per pair: transmitter and receiver positions ``(N, dim)`` and carriers ``(N,)``, made once
    per geometry, dtype and device (the filters evaluate ``h`` thousands of times per run)."""
    return g.pair_tx_positions(dtype, device), g.pair_rx_positions(dtype, device), g.pair_carriers(dtype, device)


@dataclass(frozen=True)
class MeasurementModel:
    """``z = h(x) + w`` for a geometry, a state layout and a list of measurement components.

    The measurement vector is component-major by default (``layout="component"``):
    ``[r_1..r_N, rdot_1..rdot_N, phi_1..phi_N]`` as Eq. 6 of the MDFNN paper; ``layout="pair"``
    gives ``[r_1, fd_1, r_2, fd_2, ...]`` (range + Doppler per sensor, the S-MSJPDA layout).

    ``noise_std`` holds one standard deviation per component, in that component's unit
    (m, m/s, Hz, s, rad); ``R`` can also take per-run deviations ``(..., n_components)``.
    ``pos_idx`` / ``vel_idx`` say where position and velocity sit in the state vector (take them
    from the motion model).
    """

    geometry: Geometry
    components: tuple[str, ...]
    noise_std: tuple[float, ...]
    pos_idx: tuple[int, ...]
    vel_idx: tuple[int, ...]
    layout: str = "component"

    def __post_init__(self) -> None:
        unknown = [c for c in self.components if c not in COMPONENTS]
        if unknown or not self.components or len(set(self.components)) != len(self.components):
            raise ConfigError(f"measurement components must be distinct names from {COMPONENTS}, got {self.components}")
        if len(self.noise_std) != len(self.components):
            raise ConfigError(f"need one noise deviation per component {self.components}, got {self.noise_std}")
        if not all(math.isfinite(s) and s > 0 for s in self.noise_std):
            raise ConfigError(f"noise deviations must be positive, got {self.noise_std}")
        if self.layout not in ("component", "pair"):
            raise ConfigError(f"layout must be 'component' or 'pair', got {self.layout!r}")
        if len(self.pos_idx) != self.geometry.dim or len(self.vel_idx) != self.geometry.dim:
            raise ConfigError(
                f"state has {len(self.pos_idx)}-D positions but the geometry is {self.geometry.dim}-D "
                "(use Geometry.lifted(3) for 3-D targets over ground sensors)"
            )

    @property
    def n_pairs(self) -> int:
        return self.geometry.n_pairs

    @property
    def dim_z(self) -> int:
        return len(self.components) * self.n_pairs

    @property
    def labels(self) -> list[str]:
        """Row names, e.g. ``range_1``, in measurement order."""
        names = [[f"{c}_{n + 1}" for n in range(self.n_pairs)] for c in self.components]
        return self._arrange_list(names)

    @property
    def angle_mask(self) -> torch.Tensor:
        """Boolean ``(dim_z,)``: which rows are angles (wrapped on subtraction), on the default device."""
        return self.angle_rows()

    def angle_rows(self, device: torch.device | str | None = None) -> torch.Tensor:
        """:attr:`angle_mask` on ``device`` (a tracker's: that of its inputs)."""
        rows = [[c == "azimuth"] * self.n_pairs for c in self.components]
        return torch.tensor(self._arrange_list(rows), dtype=torch.bool, device=device)

    def _arrange_list(self, per_component: list[list]) -> list:
        if self.layout == "component":
            return [v for comp in per_component for v in comp]
        return [per_component[c][n] for n in range(self.n_pairs) for c in range(len(self.components))]

    def for_pairs(self, pairs: Sequence[int]) -> "MeasurementModel":
        """The same model restricted to some pairs (sensors), in the given order: what a
        sequential multi-sensor update or a single receiver's detections are filtered with."""
        pairs = [int(p) for p in pairs]
        if not pairs or any(not 0 <= p < self.n_pairs for p in pairs):
            raise ConfigError(f"pair indices must be in [0, {self.n_pairs}), got {pairs}")
        geometry = replace(self.geometry, pairs=tuple(self.geometry.pairs[p] for p in pairs))
        return replace(self, geometry=geometry)

    def rows_for_pairs(self, pairs: Sequence[int]) -> list[int]:
        """Rows of this model's ``z`` that make up ``for_pairs(pairs)``'s ``z``, in its order."""
        pairs = [int(p) for p in pairs]
        C = len(self.components)
        full = self._arrange_list([[(c, n) for n in range(self.n_pairs)] for c in range(C)])
        where = {key: row for row, key in enumerate(full)}
        sub = self.for_pairs(pairs)._arrange_list([[(c, p) for p in pairs] for c in range(C)])
        return [where[key] for key in sub]

    def _sensors(self, x: torch.Tensor):
        return _sensor_tensors(self.geometry, x.dtype, x.device)

    def _split_state(self, x: torch.Tensor):
        return x[..., list(self.pos_idx)], x[..., list(self.vel_idx)]

    def _per_coordinate(self, x: torch.Tensor):
        """Velocity components and offsets to each pair's sensors, one ``(..., N)`` tensor per
        coordinate, plus guarded distances ``(..., N)`` and carriers ``(N,)``.

        Keeping coordinates apart makes the hot paths (simulation, filters) contiguous
        element-wise work instead of operations on tiny trailing axes.
        """
        tx, rx, fc = self._sensors(x)
        pos = [x[..., i, None] for i in self.pos_idx]
        vel = [x[..., i, None] for i in self.vel_idx]
        off_t = [p - tx[:, c] for c, p in enumerate(pos)]
        off_r = [p - rx[:, c] for c, p in enumerate(pos)]
        d_t = sum(o * o for o in off_t).sqrt().clamp_min(MIN_SENSOR_DISTANCE_M)
        d_r = sum(o * o for o in off_r).sqrt().clamp_min(MIN_SENSOR_DISTANCE_M)
        return vel, off_t, off_r, d_t, d_r, fc

    def h(self, x: torch.Tensor) -> torch.Tensor:
        """Noise-free measurement ``(..., dim_z)`` of states ``x (..., dim_x)``."""
        vel, off_t, off_r, d_t, d_r, fc = self._per_coordinate(x)
        rng = rate = None
        rows = []
        for c in self.components:
            if c in ("range", "delay"):
                rng = d_t + d_r if rng is None else rng
                rows.append(rng if c == "range" else rng / SPEED_OF_LIGHT)
            elif c in ("range_rate", "doppler"):
                if rate is None:
                    rate = sum(v * (ot / d_t + orr / d_r) for v, ot, orr in zip(vel, off_t, off_r))
                rows.append(rate if c == "range_rate" else -rate * fc / SPEED_OF_LIGHT)
            else:
                rows.append(torch.atan2(off_r[0], off_r[1]))
        return self._stack(rows, n_trailing=0)

    def jacobian(self, x: torch.Tensor) -> torch.Tensor:
        """Analytic Jacobian ``dh/dx`` ``(..., dim_z, dim_x)``.

        Rows: ``dr/dp = u_tx + u_rx``; ``drdot/dp = sum_s (v - u_s (u_s . v)) / |p - s|`` and
        ``drdot/dv = u_tx + u_rx``; ``dphi/d(x, y) = (dy, -dx) / (dx^2 + dy^2)`` at the receiver;
        Doppler and delay are the range-rate and range rows scaled by ``-f_c / c`` and ``1 / c``.
        Computed per coordinate on ``(..., N)`` tensors, like :meth:`h`.
        """
        D = len(self.pos_idx)
        vel, off_t, off_r, d_t, d_r, fc = self._per_coordinate(x)
        u_t = [o / d_t for o in off_t]
        u_r = [o / d_r for o in off_r]
        grad_r = [a + b for a, b in zip(u_t, u_r)]  # d r / d p_c, also d rdot / d v_c
        uv_t = sum(u * v for u, v in zip(u_t, vel))
        uv_r = sum(u * v for u, v in zip(u_r, vel))
        grad_rate = [(v - ut * uv_t) / d_t + (v - ur * uv_r) / d_r for v, ut, ur in zip(vel, u_t, u_r)]
        rho2 = (off_r[0] ** 2 + off_r[1] ** 2).clamp_min(MIN_SENSOR_DISTANCE_M**2)
        zero = torch.zeros_like(d_t)
        grad_az = [off_r[1] / rho2, -off_r[0] / rho2] + [zero] * (D - 2)
        blocks = []  # per component: (d/dp list, d/dv list), each entry (..., N)
        for c in self.components:
            if c == "range":
                blocks.append((grad_r, None))
            elif c == "delay":
                blocks.append(([g / SPEED_OF_LIGHT for g in grad_r], None))
            elif c == "range_rate":
                blocks.append((grad_rate, grad_r))
            elif c == "doppler":
                scale = -fc / SPEED_OF_LIGHT
                blocks.append(([g * scale for g in grad_rate], [g * scale for g in grad_r]))
            else:
                blocks.append((grad_az, None))
        rows = []
        for d_pos, d_vel in blocks:
            jac = torch.zeros(*d_t.shape, x.shape[-1], dtype=x.dtype, device=x.device)
            for c in range(D):
                jac[..., self.pos_idx[c]] = d_pos[c]
                if d_vel is not None:
                    jac[..., self.vel_idx[c]] = d_vel[c]
            rows.append(jac)
        return self._stack(rows, n_trailing=1)

    def _stack(self, rows: list[torch.Tensor], n_trailing: int) -> torch.Tensor:
        """Per-component ``(..., N, *trailing)`` tensors -> ``(..., dim_z, *trailing)``."""
        axis = -2 - n_trailing  # the new component axis, just before the pair axis
        stacked = torch.stack(rows, dim=axis)  # (..., C, N, *trailing)
        if self.layout == "pair":
            stacked = stacked.transpose(axis, axis + 1)
        lead = stacked.shape[: stacked.dim() + axis]
        return stacked.reshape(*lead, self.dim_z, *stacked.shape[stacked.dim() + axis + 2 :])

    def std_vector(self, noise_std: torch.Tensor | Sequence[float] | None = None, dtype=torch.float64, device=None) -> torch.Tensor:
        """Per-row standard deviations ``(..., dim_z)`` from per-component ones ``(..., C)``."""
        s = torch.as_tensor(self.noise_std if noise_std is None else noise_std, dtype=dtype, device=device)
        if s.shape[-1] != len(self.components):
            raise ConfigError(f"expected {len(self.components)} deviations per run, got shape {tuple(s.shape)}")
        per_pair = s.unsqueeze(-1).expand(*s.shape, self.n_pairs)  # (..., C, N)
        return self._stack(list(per_pair.unbind(-2)), n_trailing=0)

    def R(self, noise_std: torch.Tensor | Sequence[float] | None = None, dtype=torch.float64, device=None) -> torch.Tensor:
        """Diagonal measurement covariance ``(..., dim_z, dim_z)``; per-run deviations allowed."""
        return torch.diag_embed(self.std_vector(noise_std, dtype, device) ** 2)

    def residual(self, z: torch.Tensor, z_pred: torch.Tensor) -> torch.Tensor:
        """``z - z_pred`` with angle rows wrapped to (-pi, pi]."""
        d = z - z_pred
        return torch.where(self.angle_rows(d.device), wrap_angle(d), d)

    def near_sensor(self, x: torch.Tensor, radius_m: float) -> torch.Tensor:
        """Boolean ``(...,)``: the target is within ``radius_m`` of any transmitter or receiver."""
        pos, _ = self._split_state(x)
        tx, rx, _ = self._sensors(x)
        sensors = torch.cat([tx, rx])
        dist = torch.linalg.vector_norm(pos.unsqueeze(-2) - sensors, dim=-1)
        return (dist < radius_m).any(-1)

    def sample(self, x: torch.Tensor, noise_std: torch.Tensor | None = None, generator: torch.Generator | None = None) -> torch.Tensor:
        """Noisy measurements ``h(x) + w`` with angles wrapped; ``noise_std`` per run ``(..., C)`` broadcasts over time."""
        z = self.h(x)
        std = self.std_vector(noise_std, x.dtype, x.device)
        if noise_std is not None and std.dim() < z.dim():
            std = std.reshape(*std.shape[:-1], *([1] * (z.dim() - std.dim())), std.shape[-1])
        noise = standard_normal(z.shape, generator, z.dtype, z.device)
        z = z.addcmul_(noise, std)
        angles = self.angle_rows(z.device).nonzero().squeeze(-1)
        if len(angles):
            z[..., angles] = wrap_angle(z[..., angles])
        return z


@dataclass(frozen=True, eq=False)
class LinearMeasurementModel:
    """``z = H x + w`` with a fixed ``H (dim_z, dim_x)``: position fixes (SI+KF), the
    linear-Gaussian checks and any tracker that measures the state directly.

    Offers the part of :class:`MeasurementModel`'s interface the filters use (``dim_z``,
    ``angle_mask``, ``h``, ``jacobian``, ``residual``, ``R``); no row is an angle.
    """

    H: torch.Tensor
    noise_std: tuple[float, ...]

    def __post_init__(self) -> None:
        if self.H.dim() != 2:
            raise ConfigError(f"H must be (dim_z, dim_x), got shape {tuple(self.H.shape)}")
        if len(self.noise_std) != self.H.shape[0] or not all(math.isfinite(s) and s > 0 for s in self.noise_std):
            raise ConfigError(f"need {self.H.shape[0]} positive noise deviations, got {self.noise_std}")

    @classmethod
    def position(cls, dim_x: int, pos_idx: Sequence[int], noise_std_m: float,
                 device: torch.device | str | None = None) -> "LinearMeasurementModel":
        """Direct position measurement (m) with the same deviation on every axis; ``H`` on ``device``."""
        H = torch.zeros(len(pos_idx), dim_x, dtype=torch.float64, device=device)
        H[range(len(pos_idx)), list(pos_idx)] = 1.0
        return cls(H, (float(noise_std_m),) * len(pos_idx))

    @property
    def dim_z(self) -> int:
        return self.H.shape[0]

    @property
    def angle_mask(self) -> torch.Tensor:
        return self.angle_rows()

    def angle_rows(self, device: torch.device | str | None = None) -> torch.Tensor:
        return torch.zeros(self.dim_z, dtype=torch.bool, device=device)

    def h(self, x: torch.Tensor) -> torch.Tensor:
        return x @ self.H.to(x).transpose(-1, -2)

    def jacobian(self, x: torch.Tensor) -> torch.Tensor:
        return self.H.to(x).expand(*x.shape[:-1], *self.H.shape)

    def residual(self, z: torch.Tensor, z_pred: torch.Tensor) -> torch.Tensor:
        return z - z_pred

    def R(self, noise_std: torch.Tensor | Sequence[float] | None = None, dtype=torch.float64, device=None) -> torch.Tensor:
        s = torch.as_tensor(self.noise_std if noise_std is None else noise_std, dtype=dtype, device=device)
        return torch.diag_embed(s**2)

    def sample(self, x: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        std = torch.as_tensor(self.noise_std, dtype=x.dtype, device=x.device)
        return self.h(x) + standard_normal((*x.shape[:-1], self.dim_z), generator, x.dtype, x.device) * std
