"""Track management shared by the multi-target trackers: tracks that start, confirm and end.

A tracker that manages its own tracks keeps them in a :class:`TrackTable` (a padded table of
``C`` slots per run, batched over runs) and, at every scan, after its association and update:

1. tells the table which tracks were *hit* (detected at ``>= hit_pairs`` pairs) and which were
   *missed* (detected at none): :meth:`TrackTable.record`;
2. applies the :class:`Confirmer` (M-of-N over a tentative track's first ``n`` scans) and the
   :class:`Deleter` (consecutive misses of a confirmed track, covariance growth):
   :meth:`TrackTable.manage`;
3. starts tentative tracks from the detections no track gated, with the :class:`FixInitiator`
   (a multi-pair position fix in the bistatic measurement space): :meth:`TrackTable.add`;
4. reports its confirmed tracks: :meth:`TrackTable.report`, into a :class:`TrackReport` whose
   slots are track ids (numbered in order of confirmation, per run; never reused).

The *oracle initiator* (each target's track started at its birth from the truth plus a prior
draw, one slot per target) is no component here: it is the ``initiation: oracle`` option of the
method kinds, kept as a reference row and named so in every report.

Shapes: ``B`` runs, ``C`` table slots, ``S`` pairs (sensors), ``M`` detections per list, ``n``
state dimension, ``d`` measurement components per pair.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.gaussian import Gaussian
from ..measurements import MeasurementModel
from .gating import gate_threshold

FREE, TENTATIVE, CONFIRMED = 0, 1, 2


@dataclass(frozen=True)
class Confirmer:
    """M-of-N confirmation: a tentative track is confirmed once ``m`` of its first ``n`` scans
    (its initiation scan counts as a hit) were hits; one that can no longer get there is
    deleted."""

    m: int = 2
    n: int = 3

    def __post_init__(self) -> None:
        require(1 <= self.m <= self.n <= 62, f"confirmation needs 1 <= M <= N <= 62 (M of N scans); got M = {self.m}, "
                                             f"N = {self.n}: a track could never be confirmed")

    def confirms(self, hits: torch.Tensor) -> torch.Tensor:
        return hits >= self.m

    def hopeless(self, hits: torch.Tensor, age: torch.Tensor) -> torch.Tensor:
        """``hits`` so far over ``age + 1`` scans: even hits at every scan left of the first
        ``n`` can not make ``m``."""
        return hits + (self.n - 1 - age).clamp(min=0) < self.m


@dataclass(frozen=True)
class Deleter:
    """A confirmed track is deleted after ``misses`` scans in a row without a detection at any
    pair, or when its position deviation (root of the largest eigenvalue of the position block)
    exceeds ``max_position_sd_m``."""

    misses: int = 2
    max_position_sd_m: float = math.inf

    def __post_init__(self) -> None:
        require(self.misses >= 1, f"a deleter needs misses >= 1 (0 would delete every track at its birth), got "
                                  f"{self.misses}")
        require(self.max_position_sd_m > 0, f"max_position_sd_m must be positive, got {self.max_position_sd_m}")


@dataclass(frozen=True)
class FixInitiator:
    """Tentative tracks from the detections no track gated, one per group of detections of
    ``>= min_pairs`` different pairs whose position fixes agree.

    Each pair's (bistatic range, azimuth) fixes a position in the plane: the receiver's ray at
    that azimuth meets the ellipse with the pair's foci. Its covariance is the linearised
    ``H^-1 R H^-T`` (``H`` the model's Jacobian of range and azimuth by position). Two fixes of
    different pairs agree when their squared Mahalanobis distance under the sum of their
    covariances is within the chi-square gate ``gate_probability`` (2 degrees of freedom). A
    group's position is the information-weighted mean of its fixes; its velocity the linear
    least-squares fit of the group's range-rates (or Dopplers, linear in velocity at a known
    position) under a prior ``N(0, velocity_sd_mps^2)`` per axis; other state entries (e.g.
    acceleration) start at 0 with deviations ``other_sd`` (the scenario's initiation prior).
    """

    velocity_sd_mps: float = 20.0
    min_pairs: int = 2
    gate_probability: float = 0.999

    def __post_init__(self) -> None:
        require(self.velocity_sd_mps > 0 and math.isfinite(self.velocity_sd_mps),
                f"the initiator's velocity deviation must be positive, got {self.velocity_sd_mps}")
        require(self.min_pairs >= 1, f"min_pairs must be at least 1, got {self.min_pairs}")
        require(0.5 <= self.gate_probability < 1.0, f"gate probability must be in [0.5, 1), got {self.gate_probability}")

    def check(self, model: MeasurementModel, what: str = "initiation from detections") -> None:
        """One-line refusal of a model this initiator can not fix positions from."""
        if "azimuth" not in model.components or "range" not in model.components or model.geometry.dim != 2:
            raise ConfigError(f"{what} fixes positions from (bistatic range, azimuth) in 2-D; the detections measure "
                              f"{list(model.components)} in {model.geometry.dim}-D (use initiation: oracle)")
        require(self.min_pairs <= model.n_pairs, f"min_pairs ({self.min_pairs}) is more than the {model.n_pairs} pairs: "
                                                 "no track could ever start")

    def fixes(self, z: torch.Tensor, model: MeasurementModel, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Position fixes of detections ``z (B, S, M, d)`` (pair ``s`` measured by ``model``'s pair
        ``s``; states of dimension ``n``): positions ``(B, S, M, 2)``, covariances
        ``(B, S, M, 2, 2)`` and ``ok (B, S, M)`` (a fix exists: range beyond the baseline,
        finite, ``H`` invertible)."""
        comps = model.components
        r, az = z[..., comps.index("range")], z[..., comps.index("azimuth")]
        tx = model.geometry.pair_tx_positions(z.dtype)[:, None, :]  # (S, 1, 2)
        rx = model.geometry.pair_rx_positions(z.dtype)[:, None, :]
        base = rx - tx
        u = torch.stack([torch.sin(az), torch.cos(az)], -1)  # azimuth clockwise from north
        L2 = (base * base).sum(-1)
        denom = 2 * (r + (base * u).sum(-1))
        rho = (r * r - L2) / denom
        pos = rx + rho.unsqueeze(-1) * u
        ok = torch.isfinite(rho) & (rho > 0) & (r * r > L2)
        pos = torch.where(ok.unsqueeze(-1), pos, torch.zeros((), dtype=z.dtype))
        # H = d(range, azimuth)/d(position) of each pair from the model's own Jacobian
        pi = list(model.pos_idx)
        H = []
        for s in range(model.n_pairs):
            sub = model.for_pairs([s])
            state = pos.new_zeros(*pos.shape[:1], pos.shape[2], n)
            state[..., pi] = pos[:, s]
            J = sub.jacobian(state)  # (B, M, d, n)
            H.append(J[..., [comps.index("range"), comps.index("azimuth")], :][..., pi])
        H = torch.stack(H, 1)  # (B, S, M, 2, 2)
        sd = torch.tensor([model.noise_std[comps.index("range")], model.noise_std[comps.index("azimuth")]], dtype=z.dtype)
        det = H[..., 0, 0] * H[..., 1, 1] - H[..., 0, 1] * H[..., 1, 0]
        # the two gradients nearly parallel (the sine of their angle below 1e-6): no fix along it
        ok = ok & (det.abs() > 1e-6 * H[..., 0, :].norm(dim=-1) * H[..., 1, :].norm(dim=-1))
        H = torch.where(ok[..., None, None], H, torch.eye(2, dtype=z.dtype))
        Hinv = torch.linalg.inv(H)
        return pos, Hinv @ torch.diag(sd**2) @ Hinv.transpose(-1, -2), ok

    def groups(self, pos: torch.Tensor, cov: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
        """Groups of agreeing fixes ``(B, G, S)`` int64: the detection of each pair in the group
        (-1: none), ``G`` groups of ``>= min_pairs`` pairs, padded with all -1 rows.

        Anchored greedily, batched over runs: for each pair ``a`` in turn, every unused fix of
        ``a`` takes, from each later pair, the nearest unused fix it agrees with; where two anchors
        want the same fix the nearer keeps it (the other goes without). A fix is used once.
        """
        B, S, M = ok.shape
        gamma = gate_threshold(self.gate_probability, 2)
        free = ok.clone()
        rows = []
        ar = torch.arange(M)
        for a in range(S):
            members = torch.full((B, M, S), -1, dtype=torch.int64)
            members[..., a] = torch.where(free[:, a], ar, torch.full_like(ar, -1))
            for b in range(a + 1, S):
                diff = pos[:, a, :, None] - pos[:, b, None, :]  # (B, M, M, 2)
                both = cov[:, a, :, None] + cov[:, b, None, :]
                d2 = (diff.unsqueeze(-2) @ torch.linalg.solve(both, diff.unsqueeze(-1))).squeeze(-1).squeeze(-1)
                agree = (d2 <= gamma) & free[:, a, :, None] & free[:, b, None, :]
                d2 = torch.where(agree, d2, torch.full_like(d2, math.inf))
                best_d, best = d2.min(-1)  # (B, M): each anchor's nearest agreeing fix of pair b
                has = torch.isfinite(best_d)
                # one anchor per fix of pair b: the nearest of those that chose it
                claim = torch.full((B, M), math.inf, dtype=d2.dtype).scatter_reduce(
                    1, best, torch.where(has, best_d, torch.full_like(best_d, math.inf)), "amin")
                keep = has & (best_d <= claim.gather(1, best))
                # exact ties: the lowest anchor index keeps the fix
                first = torch.full((B, M), M, dtype=torch.int64).scatter_reduce(
                    1, best, torch.where(keep, ar.expand(B, M), torch.full_like(best, M)), "amin")
                keep = keep & (first.gather(1, best) == ar)
                members[..., b] = torch.where(keep, best, torch.full_like(best, -1))
            size = (members >= 0).sum(-1)
            good = size >= self.min_pairs
            members = torch.where(good[..., None], members, torch.full_like(members, -1))
            for b in range(a, S):  # mark what the accepted groups used
                idx = members[..., b]
                used = torch.zeros(B, M + 1, dtype=torch.bool).scatter(1, torch.where(idx >= 0, idx, M), True)[:, :M]
                free[:, b] &= ~used
            rows.append(members)
        out = torch.cat(rows, 1)  # (B, S*M, S)
        real = (out >= 0).any(-1)
        G = int(real.sum(-1).max()) if real.numel() else 0
        order = torch.argsort((~real).to(torch.int8), dim=1, stable=True)[:, :G]
        return out.gather(1, order[..., None].expand(B, G, S))

    def states(self, z: torch.Tensor, groups: torch.Tensor, pos: torch.Tensor, cov: torch.Tensor, model: MeasurementModel,
               n: int, other_sd: torch.Tensor) -> tuple[Gaussian, torch.Tensor]:
        """Initial Gaussians ``(B, G, n)`` of ``groups (B, G, S)`` (see the class docstring) and
        which groups are real ``(B, G)``."""
        B, G, S = groups.shape
        real = (groups >= 0).any(-1)
        has = groups >= 0  # (B, G, S)
        idx = groups.clamp(min=0)
        take = lambda t: t.gather(2, idx.transpose(1, 2)[(...,) + (None,) * (t.dim() - 3)].expand(
            B, S, G, *t.shape[3:])).transpose(1, 2)  # (B, S, M, ...) -> (B, G, S, ...)
        p_i, P_i, z_i = take(pos), take(cov), take(z)
        eye2 = torch.eye(2, dtype=z.dtype)
        info = torch.where(has[..., None, None], torch.linalg.inv(torch.where(has[..., None, None], P_i, eye2)),
                           torch.zeros((), dtype=z.dtype))
        Pp = torch.linalg.inv(info.sum(2) + torch.where(real, 0.0, 1.0)[..., None, None] * eye2)
        p = (Pp @ (info @ p_i.unsqueeze(-1)).sum(2)).squeeze(-1)  # (B, G, 2)
        x = z.new_zeros(B, G, n)
        pi, vi = list(model.pos_idx), list(model.vel_idx)
        x[..., pi] = p
        # velocity: the rate rows are linear in velocity at a known position
        rate = [c for c in model.components if c in ("range_rate", "doppler")]
        prec = torch.eye(2, dtype=z.dtype) / self.velocity_sd_mps**2
        Lam = prec.expand(B, G, 2, 2).clone()
        eta = z.new_zeros(B, G, 2)
        if rate:
            c = model.components.index(rate[0])
            var = model.noise_std[c] ** 2
            for s in range(S):
                sub = model.for_pairs([s])
                g = sub.jacobian(x)[..., c, :][..., vi]  # (B, G, 2)
                w = has[..., s].to(z.dtype) / var
                zr = torch.where(has[..., s], z_i[..., s, c], torch.zeros((), dtype=z.dtype))
                Lam = Lam + w[..., None, None] * g.unsqueeze(-1) * g.unsqueeze(-2)
                eta = eta + (w * zr)[..., None] * g
        Pv = torch.linalg.inv(Lam)
        x[..., vi] = (Pv @ eta.unsqueeze(-1)).squeeze(-1)
        P = torch.diag_embed(other_sd.to(z.dtype) ** 2).expand(B, G, n, n).clone()
        P[..., pi, :] = 0.0
        P[..., :, pi] = 0.0
        P[..., vi, :] = 0.0
        P[..., :, vi] = 0.0
        P[..., torch.tensor(pi)[:, None], torch.tensor(pi)] = Pp
        P[..., torch.tensor(vi)[:, None], torch.tensor(vi)] = Pv
        return Gaussian(x, P), real

    def initiate(self, z: torch.Tensor, unused: torch.Tensor, model: MeasurementModel, n: int,
                 other_sd: torch.Tensor) -> tuple[Gaussian, torch.Tensor]:
        """Tentative tracks ``(B, G, n)`` and which are real ``(B, G)`` from the detections
        ``z (B, S, M, d)`` marked ``unused (B, S, M)``."""
        pos, cov, ok = self.fixes(z, model, n)
        groups = self.groups(pos, cov, ok & unused)
        return self.states(z, groups, pos, cov, model, n, other_sd)


@dataclass(frozen=True)
class Management:
    """What a tracker that starts its own tracks is assembled with: the ``initiator``, the
    ``confirmer``, the ``deleter``, how many pairs make a hit (``hit_pairs``) and the deviations
    ``other_sd (n,)`` of the state entries the initiator does not fix (the scenario's initiation
    prior), and the existence model: ``survival`` probability per scan, ``initial_existence`` of a
    new track and ``report_existence``, the existence a confirmed track needs to be reported at a
    scan (a track that missed at every pair drops below it at once; see
    :meth:`TrackTable.update_existence`)."""

    initiator: FixInitiator
    confirmer: Confirmer
    deleter: Deleter
    other_sd: torch.Tensor
    hit_pairs: int = 2
    survival: float = 0.99
    initial_existence: float = 0.5
    report_existence: float = 0.5

    def __post_init__(self) -> None:
        for name in ("survival", "initial_existence", "report_existence"):
            v = getattr(self, name)
            require(0.0 < v < 1.0, f"{name} must be in (0, 1), got {v}")

    def check(self, model: MeasurementModel, what: str) -> None:
        """One-line refusals of settings that could never confirm a track on ``model``."""
        self.initiator.check(model, what)
        require(1 <= self.hit_pairs <= model.n_pairs, f"{what}: hit_pairs ({self.hit_pairs}) must be in [1, "
                                                      f"{model.n_pairs}] (the pairs): a track could never be confirmed")


def parked_state(model: MeasurementModel, n: int, dtype=torch.float64) -> torch.Tensor:
    """A state ``(n,)`` far from every sensor, at rest: what free slots hold."""
    sensors = torch.cat([model.geometry.pair_tx_positions(dtype), model.geometry.pair_rx_positions(dtype)])
    x = torch.zeros(n, dtype=dtype)
    x[list(model.pos_idx)] = sensors.abs().amax(0) + 1.0e6
    return x


@dataclass
class TrackTable:
    """The tracks of ``B`` runs in ``C`` slots (``C`` grows as needed).

    ``g`` the Gaussians ``(B, C, n)``; ``status (B, C)`` :data:`FREE`, :data:`TENTATIVE` or
    :data:`CONFIRMED`; ``hits (B, C)`` hits so far (the initiation scan counts) and ``age (B, C)``
    scans since initiation; ``misses (B, C)`` scans in a row without a detection at any pair;
    ``track_id (B, C)`` the reported id of a confirmed track (-1 before), ``next_id (B,)``;
    ``existence (B, C)`` the probability that the track is a target (IPDA).
    A free slot holds a parked state (far, unit covariance) so batched filter steps stay finite.
    """

    g: Gaussian
    status: torch.Tensor
    hits: torch.Tensor
    age: torch.Tensor
    misses: torch.Tensor
    track_id: torch.Tensor
    next_id: torch.Tensor
    park: torch.Tensor
    existence: torch.Tensor

    @classmethod
    def empty(cls, B: int, n: int, park: torch.Tensor, capacity: int = 8) -> "TrackTable":
        """No tracks; ``park (n,)`` the state free slots hold."""
        x = park.expand(B, capacity, n).clone()
        P = torch.eye(n, dtype=park.dtype).expand(B, capacity, n, n).clone()
        z = lambda: torch.zeros(B, capacity, dtype=torch.int64)
        return cls(Gaussian(x, P), z(), z(), z(), z(), torch.full((B, capacity), -1, dtype=torch.int64),
                   torch.zeros(B, dtype=torch.int64), park, torch.zeros(B, capacity, dtype=park.dtype))

    @property
    def active(self) -> torch.Tensor:
        return self.status != FREE

    @property
    def confirmed(self) -> torch.Tensor:
        return self.status == CONFIRMED

    def _grow(self, capacity: int) -> None:
        B, C, n = self.g.x.shape
        extra = capacity - C
        if extra <= 0:
            return
        more = TrackTable.empty(B, n, self.park, extra)
        self.g = Gaussian(torch.cat([self.g.x, more.g.x], 1), torch.cat([self.g.P, more.g.P], 1))
        for name in ("status", "hits", "age", "misses", "track_id", "existence"):
            setattr(self, name, torch.cat([getattr(self, name), getattr(more, name)], 1))

    def free(self, where: torch.Tensor) -> None:
        """Delete the tracks at ``where (B, C)``: their slots are parked and free again."""
        self.status = torch.where(where, FREE, self.status)
        self.existence = torch.where(where, 0.0, self.existence)
        self.track_id = torch.where(where, -1, self.track_id)
        self.g = Gaussian(torch.where(where[..., None], self.park, self.g.x),
                          torch.where(where[..., None, None], torch.eye(self.g.x.shape[-1], dtype=self.g.x.dtype),
                                      self.g.P))

    def predict_existence(self, survival: float) -> None:
        """A track survives a scan with probability ``survival``."""
        self.existence = self.existence * survival

    def update_existence(self, ratio: torch.Tensor, pd_pg: float) -> None:
        """One pair's IPDA update (Musicki, Evans & Stankovic 1994): with ``ratio (B, C)`` the sum
        over the gated detections of their likelihood over the clutter density and ``pd_pg`` the
        detection times gate probability, ``delta = pd_pg (1 - ratio)`` and the existence becomes
        ``(1 - delta) e / (1 - delta e)``; a pair that saw nothing in the gate multiplies the odds
        by ``1 - pd_pg``."""
        delta = pd_pg * (1.0 - ratio)
        e = self.existence
        self.existence = torch.where(self.active, ((1.0 - delta) * e / (1.0 - delta * e)).clamp(0.0, 1.0), e)

    def record(self, detected_pairs: torch.Tensor, hit_pairs: int) -> None:
        """After a scan's update: ``detected_pairs (B, C)`` at how many pairs each track was
        detected (its likeliest association there a detection); a hit needs ``hit_pairs``."""
        act = self.active
        self.age = torch.where(act, self.age + 1, self.age)
        self.hits = torch.where(act & (detected_pairs >= hit_pairs), self.hits + 1, self.hits)
        self.misses = torch.where(act & (detected_pairs == 0), self.misses + 1, torch.where(act, 0, self.misses))

    def manage(self, confirmer: Confirmer, deleter: Deleter, pos_idx: list[int]) -> None:
        """Confirm, then delete (see the module docstring)."""
        tent = self.status == TENTATIVE
        new = tent & confirmer.confirms(self.hits)
        rank = new.to(torch.int64).cumsum(1) - 1
        self.track_id = torch.where(new, self.next_id[:, None] + rank, self.track_id)
        self.next_id = self.next_id + new.sum(1)
        self.status = torch.where(new, CONFIRMED, self.status)
        drop = (self.status == TENTATIVE) & confirmer.hopeless(self.hits, self.age)
        conf = self.status == CONFIRMED
        drop |= conf & (self.misses >= deleter.misses)
        if math.isfinite(deleter.max_position_sd_m):
            Pp = self.g.P[..., pos_idx, :][..., pos_idx]
            drop |= conf & (torch.linalg.eigvalsh(Pp)[..., -1] > deleter.max_position_sd_m**2)
        self.free(drop)

    def add(self, g: Gaussian, real: torch.Tensor, initial_existence: float = 0.5) -> None:
        """Start tentative tracks ``g (B, G, n)`` where ``real (B, G)`` in free slots."""
        if not bool(real.any()):
            return
        count = real.sum(1)
        need = int((count - (~self.active).sum(1)).max())
        if need > 0:
            self._grow(self.g.x.shape[1] + max(need, self.g.x.shape[1] // 2))
        B, C, n = self.g.x.shape
        G = real.shape[1]
        free = ~self.active
        slot_rank = free.to(torch.int64).cumsum(1) - 1  # (B, C): rank of each free slot
        new_rank = real.to(torch.int64).cumsum(1) - 1  # (B, G)
        # new track j goes to the free slot whose rank is its rank
        filled = free & (slot_rank < count[:, None])
        # by_rank[b, r]: the index in g of run b's new track of rank r (column G collects the others)
        by_rank = torch.zeros(B, G + 1, dtype=torch.int64).scatter(
            1, torch.where(real, new_rank, torch.full_like(new_rank, G)), torch.arange(G).expand(B, G))
        j = by_rank.gather(1, torch.where(filled, slot_rank, 0))  # (B, C): the new track that fills the slot
        xj = g.x.gather(1, j[..., None].expand(B, C, n))
        Pj = g.P.gather(1, j[..., None, None].expand(B, C, n, n))
        self.g = Gaussian(torch.where(filled[..., None], xj, self.g.x), torch.where(filled[..., None, None], Pj, self.g.P))
        self.status = torch.where(filled, TENTATIVE, self.status)
        for name, value in (("hits", 1), ("age", 0), ("misses", 0)):
            setattr(self, name, torch.where(filled, value, getattr(self, name)))
        self.existence = torch.where(filled, initial_existence, self.existence)
        self.track_id = torch.where(filled, -1, self.track_id)


@dataclass
class TrackReport:
    """Confirmed tracks per run and scan as reported: ``x (B, K, T, n)``, ``P (B, K, T, n, n)``,
    ``exists (B, K, T)``, slot ``t`` the run's ``t``-th confirmed track (``T`` grows as needed),
    and ``existence (B, K, T)`` of every confirmed track, reported or not (0 elsewhere)."""

    x: torch.Tensor
    P: torch.Tensor
    exists: torch.Tensor
    existence: torch.Tensor

    @classmethod
    def empty(cls, B: int, K: int, n: int, dtype=torch.float64) -> "TrackReport":
        return cls(torch.full((B, K, 0, n), math.nan, dtype=dtype), torch.zeros(B, K, 0, n, n, dtype=dtype),
                   torch.zeros(B, K, 0, dtype=torch.bool), torch.zeros(B, K, 0, dtype=dtype))

    def write(self, k: int, table: TrackTable, report_existence: float = 0.0) -> None:
        """The table's confirmed tracks at scan ``k`` whose existence is at least ``report_existence``."""
        conf = table.confirmed
        if not bool(conf.any()):
            return
        T = int(table.track_id.max()) + 1
        B, K, T0, n = self.x.shape
        if T > T0:
            grow = max(T, 2 * T0) - T0
            self.x = torch.cat([self.x, self.x.new_full((B, K, grow, n), math.nan)], 2)
            self.P = torch.cat([self.P, self.P.new_zeros(B, K, grow, n, n)], 2)
            self.exists = torch.cat([self.exists, self.exists.new_zeros(B, K, grow)], 2)
            self.existence = torch.cat([self.existence, self.existence.new_zeros(B, K, grow)], 2)
        b, c = torch.nonzero(conf, as_tuple=True)
        t = table.track_id[b, c]
        self.x[b, k, t] = table.g.x[b, c]
        self.P[b, k, t] = table.g.P[b, c]
        self.existence[b, k, t] = table.existence[b, c]
        self.exists[b, k, t] = table.existence[b, c] >= report_existence

    def trimmed(self) -> "TrackReport":
        """Without the slots no run used."""
        seen = self.existence > 0
        used = int(seen.any(1).any(0).nonzero().max()) + 1 if bool(seen.any()) else 0
        return TrackReport(self.x[:, :, :used], self.P[:, :, :used], self.exists[:, :, :used],
                           self.existence[:, :, :used])
