"""Sensor geometry: transmitters (position, carrier), receivers and the bistatic pairs.

Positions are in metres in a local east-north(-up) frame: ``x`` east, ``y`` north, and ``z``
up when the geometry is 3-D. Sensors of a 2-D geometry live in the ground plane; a 3-D
geometry lets targets fly at an altitude above ground sensors (the altitude study of Table 7
in the MDFNN paper).

A *pair* (transmitter ``i``, receiver ``j``) is what the tracking literature calls a sensor: it
yields one bistatic range, range-rate / Doppler and (at the receiver) azimuth per target.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch

from .errors import GeometryError

MIN_BASELINE_M = 1.0
"""A receiver closer than this to a transmitter is rejected: the bistatic ellipse degenerates."""


@dataclass(frozen=True)
class Transmitter:
    """An illuminator of opportunity: ``position_m`` (2 or 3 values) and carrier in Hz."""

    position_m: tuple[float, ...]
    carrier_hz: float


@dataclass(frozen=True)
class Receiver:
    """A surveillance receiver at ``position_m`` (2 or 3 values)."""

    position_m: tuple[float, ...]


@dataclass(frozen=True)
class Geometry:
    """Transmitters, receivers and the ordered list of bistatic pairs ``(tx index, rx index)``.

    The pair order fixes the order of measurement rows: pair ``n`` gives ``r_n``, ``rdot_n``,
    ``phi_n``.
    """

    transmitters: tuple[Transmitter, ...]
    receivers: tuple[Receiver, ...]
    pairs: tuple[tuple[int, int], ...]

    def __post_init__(self) -> None:
        if not self.transmitters or not self.receivers:
            raise GeometryError("a geometry needs at least one transmitter and one receiver")
        dims = {len(s.position_m) for s in (*self.transmitters, *self.receivers)}
        if len(dims) != 1 or dims.pop() not in (2, 3):
            raise GeometryError("all sensor positions must have the same dimension, 2 or 3")
        for k, s in enumerate((*self.transmitters, *self.receivers)):
            if not all(math.isfinite(v) for v in s.position_m):
                raise GeometryError(f"sensor {k} has a non-finite position {s.position_m}")
        for i, tx in enumerate(self.transmitters):
            if not (math.isfinite(tx.carrier_hz) and tx.carrier_hz > 0):
                raise GeometryError(f"transmitter {i}: carrier_hz must be positive, got {tx.carrier_hz}")
        for j, a in enumerate(self.receivers):
            for k in range(j):
                if math.dist(a.position_m, self.receivers[k].position_m) < MIN_BASELINE_M:
                    raise GeometryError(f"receivers {k} and {j} are at the same position {list(a.position_m)}: "
                                        "a duplicate receiver adds no information and makes the geometry degenerate")
        for j, a in enumerate(self.transmitters):
            for k in range(j):
                b = self.transmitters[k]
                # Co-sited transmitters on different carriers are real (several FM channels on one mast).
                if math.dist(a.position_m, b.position_m) < MIN_BASELINE_M and a.carrier_hz == b.carrier_hz:
                    raise GeometryError(f"transmitters {k} and {j} are the same illuminator (same position and "
                                        f"carrier {a.carrier_hz:g} Hz); list it once")
        if not self.pairs:
            raise GeometryError("a geometry needs at least one transmitter-receiver pair")
        if len(set(self.pairs)) != len(self.pairs):
            dup = next(p for p in self.pairs if self.pairs.count(p) > 1)
            raise GeometryError(f"pair {list(dup)} is listed twice; list each transmitter-receiver pair once")
        for i, j in self.pairs:
            if not (0 <= i < len(self.transmitters) and 0 <= j < len(self.receivers)):
                raise GeometryError(f"pair ({i}, {j}) names a sensor that does not exist")
            baseline = math.dist(self.transmitters[i].position_m, self.receivers[j].position_m)
            if baseline < MIN_BASELINE_M:
                raise GeometryError(
                    f"receiver {j} is placed on transmitter {i} (baseline {baseline:.3g} m < "
                    f"{MIN_BASELINE_M} m): the bistatic pair is degenerate"
                )

    @classmethod
    def all_pairs(cls, transmitters: Sequence[Transmitter], receivers: Sequence[Receiver]) -> "Geometry":
        """Every transmitter with every receiver, transmitter-major: ``N = N_t * N_r`` pairs."""
        pairs = tuple((i, j) for i in range(len(transmitters)) for j in range(len(receivers)))
        return cls(tuple(transmitters), tuple(receivers), pairs)

    @property
    def dim(self) -> int:
        """Spatial dimension of sensor positions (2 or 3)."""
        return len(self.transmitters[0].position_m)

    @property
    def n_pairs(self) -> int:
        return len(self.pairs)

    def pair_tx_positions(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """Transmitter position of each pair, ``(N, dim)`` in m."""
        return torch.tensor([self.transmitters[i].position_m for i, _ in self.pairs], dtype=dtype, device=device)

    def pair_rx_positions(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """Receiver position of each pair, ``(N, dim)`` in m."""
        return torch.tensor([self.receivers[j].position_m for _, j in self.pairs], dtype=dtype, device=device)

    def pair_carriers(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """Carrier frequency of each pair's transmitter, ``(N,)`` in Hz."""
        return torch.tensor([self.transmitters[i].carrier_hz for i, _ in self.pairs], dtype=dtype, device=device)

    def baselines_m(self) -> list[float]:
        """Transmitter-receiver distance of each pair, in m."""
        return [math.dist(self.transmitters[i].position_m, self.receivers[j].position_m) for i, j in self.pairs]

    def lifted(self, dim: int) -> "Geometry":
        """The same geometry with positions padded with zeros (ground sensors) up to ``dim``."""
        if dim < self.dim:
            raise GeometryError(f"cannot lower a {self.dim}-D geometry to {dim}-D")
        pad = (0.0,) * (dim - self.dim)
        return Geometry(
            tuple(Transmitter(t.position_m + pad, t.carrier_hz) for t in self.transmitters),
            tuple(Receiver(r.position_m + pad) for r in self.receivers),
            self.pairs,
        )

    def to_dict(self) -> dict:
        """Plain-data form (JSON/YAML-safe), the inverse of :meth:`from_dict`."""
        return {
            "transmitters": [{"position_m": list(t.position_m), "carrier_hz": t.carrier_hz} for t in self.transmitters],
            "receivers": [{"position_m": list(r.position_m)} for r in self.receivers],
            "pairs": [list(p) for p in self.pairs],
        }

    @classmethod
    def from_dict(cls, d: dict) -> "Geometry":
        try:
            txs = tuple(Transmitter(tuple(float(v) for v in t["position_m"]), float(t["carrier_hz"])) for t in d["transmitters"])
            rxs = tuple(Receiver(tuple(float(v) for v in r["position_m"])) for r in d["receivers"])
            pairs = tuple((int(i), int(j)) for i, j in d["pairs"])
        except (KeyError, TypeError, ValueError) as exc:
            raise GeometryError(f"malformed geometry description: {exc}") from None
        return cls(txs, rxs, pairs)


def polar_position(baseline_m: float, bearing_deg: float, origin: Sequence[float] = (0.0, 0.0)) -> tuple[float, ...]:
    """Point at ``baseline_m`` from ``origin`` along ``bearing_deg`` (clockwise from north)."""
    b = math.radians(bearing_deg)
    out = [origin[0] + baseline_m * math.sin(b), origin[1] + baseline_m * math.cos(b)]
    return tuple(out + list(origin[2:]))
