"""Track management shared by the multi-target trackers: tracks that start, confirm and end.

The components of :class:`~.own_tracks.OwnTracks`, the management of a tracker that starts its
own tracks on the one tracker loop (:mod:`.loop`): the tracks live in a :class:`TrackTable` (a
padded table of ``C`` slots per run, batched over runs) and, at every scan, after the
association and update, the table:

1. tells the table which tracks were *hit* (detected at ``>= hit_pairs`` pairs) and which were
   *missed* (detected at none): :meth:`TrackTable.record`;
2. applies the :class:`Confirmer` (M-of-N over a tentative track's first ``n`` scans) and the
   :class:`Deleter` (consecutive misses of a confirmed track, covariance growth):
   :meth:`TrackTable.manage`;
3. starts tentative tracks from the detections no track explains, with an initiator of
   :mod:`.initiators` (:class:`~.fix_initiator.FixInitiator` where each pair measures azimuth, a
   multi-pair position fix; :class:`~.spherical_initiator.SphericalInitiator` from range and range-rate or
   Doppler only, combinations of one detection per pair whose joint fit passes a chi-square gate):
   :meth:`TrackTable.add`;
4. reports its confirmed tracks: :meth:`TrackTable.report`, into a :class:`TrackReport` whose
   slots are track ids (numbered in order of confirmation, per run; never reused).

The *oracle initiator* (each target's track started at its birth from the truth plus a prior
draw, one slot per target) is the other management, :class:`~.handed_births.HandedBirths`: the
``initiation: oracle`` option of the method kinds, kept as a reference row and named so in every
report.

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
from .coalescence import Coalescence
from .fix_initiator import FixInitiator
from .innovation_bias import BiasTest
from .roles import Initiator
from .spherical_initiator import SphericalInitiator

__all__ = ["FREE", "TENTATIVE", "CONFIRMED", "EXPLAINED", "EXPLAINED_BY", "MERGE_SCANS", "DELETE_EXISTENCE", "BiasTest", "Coalescence", "Confirmer", "Deleter", "FixInitiator", "SphericalInitiator",
           "Management", "TableTracks", "TrackTable", "TrackReport", "parked_state"]

FREE, TENTATIVE, CONFIRMED = 0, 1, 2

EXPLAINED_BY = ("gate", "association")
"""How a detection counts as explained by the tracks (it starts no track): :attr:`Management.explained_by`."""

MERGE_SCANS = 3
"""The duplicate-free management's coalescence window (scans), chosen on one_sky draws no recorded
study uses (seed 1000)."""

DELETE_EXISTENCE = 0.01
"""The duplicate-free management's existence deletion (:class:`Deleter`), chosen on one_sky draws
no recorded study uses (seed 1000, runs 0-7: GOSPA 41.4 m against 48.3 m without it on runs 0-3,
1e-3 gave 54.8 m there; evaluate/RESULTS.md)."""

EXPLAINED = 0.5
"""With ``explained_by: association``, a detection whose probability of being some track's is at
least this is explained (more probably a track's than clutter)."""


@dataclass(frozen=True)
class Confirmer:
    """M-of-N confirmation: a tentative track is confirmed once ``m`` of its first ``n`` scans
    (its initiation scan counts as a hit, so ``m = 1`` confirms at the scan that starts it) were
    hits; one that can no longer get there is deleted."""

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
    exceeds ``max_position_sd_m``; any track (tentative or confirmed) whose existence probability
    falls below ``min_existence`` is deleted (JIPDA's termination; 0: never). Without it, two
    tracks on one target whose JIPDA-style existences both fade (each takes half its detections)
    stay in the table unreported, and the target's detections, taken by them, seed no new track."""

    misses: int = 2
    max_position_sd_m: float = math.inf
    min_existence: float = 0.0

    def __post_init__(self) -> None:
        require(self.misses >= 1, f"a deleter needs misses >= 1 (0 would delete every track at its birth), got "
                                  f"{self.misses}")
        require(self.max_position_sd_m > 0, f"max_position_sd_m must be positive, got {self.max_position_sd_m}")
        require(0.0 <= self.min_existence < 1.0, f"delete_existence must be in [0, 1) (0: never), got {self.min_existence}")


@dataclass(frozen=True)
class Management:
    """What a tracker that starts its own tracks is assembled with: the ``initiator``, the
    ``confirmer``, the ``deleter``, how many pairs make a hit (``hit_pairs``) and the deviations
    ``other_sd (n,)`` of the state entries the initiator does not fix (the scenario's initiation
    prior), and the existence model: ``survival`` probability per scan, ``initial_existence`` of a
    new track and ``report_existence``, the existence a confirmed track needs to be reported at a
    scan (a track that missed at every pair drops below it at once; see
    :meth:`TrackTable.update_existence`); ``bias``, the innovation bias test of a tracker that
    keeps its tracks' whitened innovations (:mod:`.innovation_bias`; None: none); ``coalescence``,
    the test that merges two confirmed tracks holding one target (:mod:`.coalescence`; None: no
    merging); ``shared_existence``: the existence update reads the association probabilities
    (JIPDA-style, :attr:`~.roles.AssociationStep.shared_ratio`), so a track that only shares
    another track's detections fades, instead of the bare gated likelihood sum (IPDA);
    ``explained_by``: which detections start no track, those a track gates (``gate``) or those
    whose association probability on the tracks is at least :data:`EXPLAINED` (``association``:
    :attr:`~.roles.AssociationStep.taken`)."""

    initiator: Initiator
    confirmer: Confirmer
    deleter: Deleter
    other_sd: torch.Tensor
    hit_pairs: int = 2
    survival: float = 0.99
    initial_existence: float = 0.5
    report_existence: float = 0.5
    bias: BiasTest | None = None
    coalescence: Coalescence | None = None
    shared_existence: bool = False
    explained_by: str = "gate"

    def __post_init__(self) -> None:
        for name in ("survival", "initial_existence", "report_existence"):
            v = getattr(self, name)
            require(0.0 < v < 1.0, f"{name} must be in (0, 1), got {v}")
        require(self.explained_by in EXPLAINED_BY, f"explained_by must be one of {EXPLAINED_BY}, got {self.explained_by!r}")

    @classmethod
    def defaults(cls, model: MeasurementModel, other_sd: torch.Tensor) -> "Management":
        """The management the method kinds' options give by default (``initiation: detections``
        with no other option): the fix initiator where the detections measure azimuth, else the
        spherical one, each with its defaults, 2-of-3 confirmation, deletion after 2 misses, IPDA
        existence, seeding from the detections no track gates, no coalescence test."""
        initiator = FixInitiator() if "azimuth" in model.components else SphericalInitiator()
        return cls(initiator, Confirmer(), Deleter(), other_sd)

    def check(self, model: MeasurementModel, what: str, pooled: bool = False) -> None:
        """One-line refusals of settings that could never confirm a track on ``model`` (``pooled``:
        from detection lists pooled per receiver, which only the
        :class:`~.fix_initiator.FixInitiator` reads)."""
        if pooled and not isinstance(getattr(self.initiator, "base", self.initiator), FixInitiator):
            raise ConfigError(f"{what}: tracks start from lists pooled per receiver (illuminator unknown) only where each "
                              f"pair measures azimuth (a position fix per illuminator hypothesis); the detections "
                              f"measure {list(model.components)} (use initiation: oracle)")
        self.initiator.check(model, what)
        require(1 <= self.hit_pairs <= model.n_pairs, f"{what}: hit_pairs ({self.hit_pairs}) must be in [1, "
                                                      f"{model.n_pairs}] (the pairs): a track could never be confirmed")


def parked_state(model: MeasurementModel, n: int, dtype=torch.float64, device=None) -> torch.Tensor:
    """A state ``(n,)`` on ``device``, far from every sensor, at rest: what free slots hold."""
    sensors = torch.cat([model.geometry.pair_tx_positions(dtype, device), model.geometry.pair_rx_positions(dtype, device)])
    x = torch.zeros(n, dtype=dtype, device=device)
    x[list(model.pos_idx)] = sensors.abs().amax(0) + 1.0e6
    return x


@dataclass
class TrackTable:
    """The tracks of ``B`` runs in ``C`` slots (``C`` grows as needed).

    ``g`` the Gaussians ``(B, C, n)``; ``status (B, C)`` :data:`FREE`, :data:`TENTATIVE` or
    :data:`CONFIRMED`; ``hits (B, C)`` hits so far (the initiation scan counts) and ``age (B, C)``
    scans since initiation; ``misses (B, C)`` scans in a row without a detection at any pair;
    ``track_id (B, C)`` the reported id of a confirmed track (-1 before), ``next_id (B,)``;
    ``existence (B, C)`` the probability that the track is a target (IPDA); ``bias_mean (B, C, S,
    d)`` the exponentially weighted means of its whitened innovations per pair (None until a
    tracker with an innovation bias test folds one in, :meth:`update_bias`).
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
    bias_mean: torch.Tensor | None = None

    @classmethod
    def empty(cls, B: int, n: int, park: torch.Tensor, capacity: int = 8) -> "TrackTable":
        """No tracks; ``park (n,)`` the state free slots hold."""
        x = park.expand(B, capacity, n).clone()
        dev = park.device
        P = torch.eye(n, dtype=park.dtype, device=dev).expand(B, capacity, n, n).clone()
        z = lambda: torch.zeros(B, capacity, dtype=torch.int64, device=dev)
        return cls(Gaussian(x, P), z(), z(), z(), z(), torch.full((B, capacity), -1, dtype=torch.int64, device=dev),
                   torch.zeros(B, dtype=torch.int64, device=dev), park, torch.zeros(B, capacity, dtype=park.dtype, device=dev))

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
        if self.bias_mean is not None:
            self.bias_mean = torch.cat([self.bias_mean, self.bias_mean.new_zeros(B, extra, *self.bias_mean.shape[2:])], 1)

    def _clear_bias(self, where: torch.Tensor) -> None:
        if self.bias_mean is not None:
            self.bias_mean = torch.where(where[..., None, None], self.bias_mean.new_zeros(()), self.bias_mean)

    def update_bias(self, test: BiasTest, pair: int, n_pairs: int, e: torch.Tensor) -> None:
        """Fold pair ``pair``'s whitened combined innovations ``e (B, C, d)`` of the active tracks
        past the test's burn-in (:attr:`age` counts the updates before this scan's) into
        :attr:`bias_mean` (``n_pairs`` pairs)."""
        if self.bias_mean is None:
            B, C, d = e.shape
            self.bias_mean = e.new_zeros(B, C, n_pairs, d)
        self.bias_mean = test.update(self.bias_mean, pair, e, self.active & (self.age >= test.burn_in))

    def biased(self, test: BiasTest) -> torch.Tensor:
        """``(B, C)``: the confirmed tracks the bias test flags (their innovations have a mean;
        ``age`` counts their updates, the first ``burn_in`` of which the test skips)."""
        if self.bias_mean is None:
            return torch.zeros_like(self.confirmed)
        return self.confirmed & test.flags(self.bias_mean, (self.age - test.burn_in).clamp(min=0))

    def free(self, where: torch.Tensor) -> None:
        """Delete the tracks at ``where (B, C)``: their slots are parked and free again."""
        self.status = torch.where(where, FREE, self.status)
        self._clear_bias(where)
        self.existence = torch.where(where, 0.0, self.existence)
        self.track_id = torch.where(where, -1, self.track_id)
        self.g = Gaussian(torch.where(where[..., None], self.park, self.g.x),
                          torch.where(where[..., None, None],
                                      torch.eye(self.g.x.shape[-1], dtype=self.g.x.dtype, device=self.g.x.device),
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

    def manage(self, confirmer: Confirmer, deleter: Deleter, pos_idx: list[int], bias: BiasTest | None = None) -> None:
        """Confirm, then delete (see the module docstring and :class:`Deleter`); with ``bias``
        whose action is ``delete``, a confirmed track it flags (:meth:`biased`) is deleted too."""
        self.confirm((self.status == TENTATIVE) & confirmer.confirms(self.hits))
        drop = (self.status == TENTATIVE) & confirmer.hopeless(self.hits, self.age)
        conf = self.status == CONFIRMED
        drop |= conf & (self.misses >= deleter.misses)
        if math.isfinite(deleter.max_position_sd_m):
            Pp = self.g.P[..., pos_idx, :][..., pos_idx]
            drop |= conf & (torch.linalg.eigvalsh(Pp)[..., -1] > deleter.max_position_sd_m**2)
        if bias is not None and bias.action == "delete":
            drop |= self.biased(bias)
        if deleter.min_existence > 0.0:
            drop |= self.active & (self.existence < deleter.min_existence)
        self.free(drop)

    def confirm(self, new: torch.Tensor) -> None:
        """Confirm the tentative tracks at ``new (B, C)``: each takes its run's next track id, in
        slot order."""
        rank = new.to(torch.int64).cumsum(1) - 1
        self.track_id = torch.where(new, self.next_id[:, None] + rank, self.track_id)
        self.next_id = self.next_id + new.sum(1)
        self.status = torch.where(new, CONFIRMED, self.status)

    def add(self, g: Gaussian, real: torch.Tensor, initial_existence: float | torch.Tensor = 0.5) -> None:
        """Start tentative tracks ``g (B, G, n)`` where ``real (B, G)`` in free slots, with
        ``initial_existence`` (a float, or each track's ``(B, G)``)."""
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
        by_rank = torch.zeros(B, G + 1, dtype=torch.int64, device=real.device).scatter(
            1, torch.where(real, new_rank, torch.full_like(new_rank, G)), torch.arange(G, device=real.device).expand(B, G))
        j = by_rank.gather(1, torch.where(filled, slot_rank, 0))  # (B, C): the new track that fills the slot
        xj = g.x.gather(1, j[..., None].expand(B, C, n))
        Pj = g.P.gather(1, j[..., None, None].expand(B, C, n, n))
        self.g = Gaussian(torch.where(filled[..., None], xj, self.g.x), torch.where(filled[..., None, None], Pj, self.g.P))
        self.status = torch.where(filled, TENTATIVE, self.status)
        for name, value in (("hits", 1), ("age", 0), ("misses", 0)):
            setattr(self, name, torch.where(filled, value, getattr(self, name)))
        if torch.is_tensor(initial_existence):
            initial_existence = initial_existence.to(self.existence.dtype).gather(1, j)
        self.existence = torch.where(filled, initial_existence, self.existence)
        self.track_id = torch.where(filled, -1, self.track_id)
        self._clear_bias(filled)


class TableTracks:
    """The part every management whose tracks live in a :class:`TrackTable` shares
    (:class:`~.own_tracks.OwnTracks`, :class:`~.bp_tracker.BPTracks`): the loop's tracks ``g``
    are the table's, free slots stay parked, the existence is predicted with ``survival`` and
    the active tracks associate. ``begin`` sets :attr:`table` and :attr:`report`."""

    table: TrackTable
    report: "TrackReport"

    def start_table(self, B: int, K: int, model: MeasurementModel, n: int, dtype, device=None) -> None:
        self.table = TrackTable.empty(B, n, parked_state(model, n, dtype, device))
        self.report = TrackReport.empty(B, K, n, dtype, device)

    @property
    def g(self) -> Gaussian:
        return self.table.g

    @g.setter
    def g(self, value: Gaussian) -> None:
        self.table.g = value

    def predict_table(self, survival: float) -> None:
        self.table.free(~self.table.active)  # keep free slots parked
        self.table.predict_existence(survival)

    def associating(self, k: int) -> torch.Tensor:
        return self.table.active

    def result(self) -> "TrackReport":
        return self.report.trimmed()


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
    def empty(cls, B: int, K: int, n: int, dtype=torch.float64, device=None) -> "TrackReport":
        return cls(torch.full((B, K, 0, n), math.nan, dtype=dtype, device=device),
                   torch.zeros(B, K, 0, n, n, dtype=dtype, device=device),
                   torch.zeros(B, K, 0, dtype=torch.bool, device=device), torch.zeros(B, K, 0, dtype=dtype, device=device))

    def write(self, k: int, table: TrackTable, report_existence: float = 0.0, only: torch.Tensor | None = None) -> None:
        """The table's confirmed tracks at scan ``k`` whose existence is at least ``report_existence``
        (``only (B, C)``: of these slots only)."""
        conf = table.confirmed if only is None else table.confirmed & only
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
