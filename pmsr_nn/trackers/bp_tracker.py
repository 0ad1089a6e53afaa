"""The multisensor belief-propagation (BP) tracker: a TOMB/P filter (Williams, IEEE TAES 2015)
with BP data association, pair by pair (Meyer et al., *Message passing algorithms for scalable
multitarget tracking*, Proc. IEEE 2018), on the one tracker loop (:mod:`.loop`).

Its parts:

* the association and update, :class:`~.bp_associator.BPAssociator` (sigma-point moments of
  each pair's bistatic measurement, BP association beliefs, the moment-matched update);
* the undetected targets, a Poisson intensity of mass ``mu_u`` per run spread like the clutter:
  it survives (``survival``) and grows by ``birth_rate`` per scan, and each pair's detections
  take ``Pd`` of it (:class:`~.bp_associator.Births`);
* new potential targets: where the detections measure azimuth, one behind every detection,
  seeded by that detection alone (its range/azimuth position fix and a velocity fit of its rate,
  :func:`one_detection_seed`) inside the association, so the later pairs of the same scan see it
  as a track; without azimuth, tentative tracks from the detections no track explains, with the
  management's initiator (a multi-pair fit), at ``initial_existence``;
* tracks managed by their existence (:class:`BPTracks`): a potential target whose existence
  reaches ``confirm_existence`` is confirmed (it takes a track id), one whose existence falls below
  ``delete_existence`` is deleted (tentative or confirmed), and a confirmed track is reported while
  its existence is at least ``report_existence``.

Shapes: ``B`` runs, ``K`` scans, ``C`` track slots, ``S`` pairs, ``M`` detections per list, ``n``
state dimension, ``d`` measurement components per pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..config import require
from ..errors import ConfigError
from ..filters.gaussian import Gaussian
from ..measurements import MeasurementModel
from ..motion import KinematicModel
from ..simulation.detections import Scans
from .bp_associator import Births, BPAssociator, BPStep
from .fix_initiator import FixInitiator, fix_spread, list_of_pairs
from .initiators import rate_component
from .loop import run_tracker
from .message_refiner import MessageRefiner
from .management import TENTATIVE, TableTracks, TrackReport, parked_state
from .msjpda import check_scans
from .roles import Initiator


@dataclass(frozen=True)
class BPSettings:
    """The BP tracker's model and management (module docstring).

    ``pd`` the detection probability and ``gate_probability`` the gate's; ``clutter_count``
    ``Lambda_c`` the expected clutter detections per pair and scan and ``clutter_density``
    ``lambda`` per unit of one pair's measurement space; ``survival`` per scan; ``birth_rate``
    new targets per scan and ``initial_targets`` the undetected targets expected at the first
    scan; the existence thresholds ``confirm_existence``, ``delete_existence`` and
    ``report_existence``; ``initial_existence`` of a tentative track from the initiator (without
    azimuth); ``iterations`` and ``tolerance`` the message passing's."""

    pd: float
    clutter_count: float
    clutter_density: float
    gate_probability: float = 0.999
    survival: float = 0.9975
    birth_rate: float = 0.01
    initial_targets: float = 0.01
    confirm_existence: float = 0.9
    delete_existence: float = 1e-6
    report_existence: float = 0.5
    initial_existence: float = 0.1
    iterations: int = 100
    tolerance: float = 1e-8

    def __post_init__(self) -> None:
        for name in ("confirm_existence", "delete_existence", "report_existence", "initial_existence"):
            v = getattr(self, name)
            require(0.0 < v < 1.0, f"{name} must be in (0, 1), got {v}")
        require(self.confirm_existence >= self.delete_existence,
                f"confirm_existence ({self.confirm_existence}) is below delete_existence ({self.delete_existence}): "
                "a track would be deleted before it could be confirmed")
        require(self.birth_rate >= 0.0 and self.initial_targets >= 0.0,
                f"birth_rate and initial_targets are expected numbers of targets, never negative; got "
                f"{self.birth_rate} and {self.initial_targets}")
        require(0.0 < self.survival <= 1.0, f"survival must be in (0, 1], got {self.survival}")
        require(0.0 < self.pd <= 1.0, f"the BP tracker needs 0 < Pd <= 1, got {self.pd}")
        require(self.clutter_count > 0.0 and self.clutter_density > 0.0,
                "the BP tracker needs a positive clutter count and density")

def one_detection_seed(model: MeasurementModel, n: int, other_sd: torch.Tensor, velocity_sd_mps: float,
                       dtype=torch.float64):
    """A :attr:`~.bp_associator.Births.seed`: the state behind each detection given that detection
    alone, for every pair of a scan at once, where the detections measure (bistatic range,
    azimuth): the position fix of :func:`~.fix_initiator.range_azimuth_fix`, with the covariance
    about it of the fixes of the detection's (range, azimuth) sigma points (the unscented
    transform, ``kappa = 1``), and the velocity fit of its one rate under the prior
    ``N(0, velocity_sd_mps^2)`` per axis (:func:`~.initiators.velocity_fit`); other entries as
    ``other_sd (n,)``.

    The returned ``seed(z (B, S, M, d), valid (B, S, M)) -> (Gaussian (B, S, M, n), real (B, S,
    M))`` reads pair ``s``'s view of its list in ``z[:, s]``. It computes every pair of the scan in
    one call (the seeds do not depend on the association), in the arithmetic of
    :meth:`~.fix_initiator.FixInitiator.states` for groups of one member, so it gives the same
    numbers as a call per pair. That arithmetic is written out here rather than called: ``states``
    on groups spanning every pair (one member each) fits each velocity with every pair's Jacobian,
    and made the seed about twice as slow on one_sky (cProfile of two runs, seed 1000)."""
    initiator = FixInitiator(velocity_sd_mps, min_pairs=1)
    dev = other_sd.device
    park = parked_state(model, n, dtype, dev)
    d = len(model.components)
    pi, vi = list(model.pos_idx), list(model.vel_idx)
    rate = rate_component(model)
    eye2 = torch.eye(2, dtype=dtype, device=dev)
    precision = eye2 / velocity_sd_mps**2
    base_P = torch.diag_embed(other_sd.to(dtype) ** 2)
    base_P[pi, :] = 0.0
    base_P[:, pi] = 0.0
    base_P[vi, :] = 0.0
    base_P[:, vi] = 0.0

    def seed(z: torch.Tensor, valid: torch.Tensor) -> tuple[Gaussian, torch.Tensor]:
        B, S, M = valid.shape
        pos, _, ok = initiator.fixes(z, model, n)
        spread, fine = fix_spread(z, model, pos)  # the fix's unscented covariance (the ellipse's curvature)
        real = ok & fine & valid
        # FixInitiator.states for one member: the information-weighted mean of one fix
        info = torch.where(real[..., None, None], torch.linalg.inv(torch.where(real[..., None, None], spread, eye2)),
                           z.new_zeros(()))
        Pp = torch.linalg.inv(info + torch.where(real, 0.0, 1.0)[..., None, None] * eye2)
        x = z.new_zeros(B, S, M, n)
        x[..., pi] = (Pp @ (info @ pos.unsqueeze(-1))).squeeze(-1)
        # velocity_fit of the one rate: pair s's row of the model's Jacobian at pair s's states
        Lam = precision.expand(B, S, M, 2, 2).clone()
        eta = x.new_zeros(B, S, M, 2)
        if rate is not None:
            J = model.jacobian(x).unflatten(-2, (S, d))  # (B, S, M, S, d, n): every pair's rows
            g = torch.diagonal(J[..., rate, :], dim1=1, dim2=3).movedim(-1, 1)[..., vi]  # (B, S, M, 2)
            w = real.to(z.dtype) / model.noise_std[rate] ** 2
            zr = torch.where(real, z[..., rate], z.new_zeros(()))
            Lam = Lam + w[..., None, None] * g.unsqueeze(-1) * g.unsqueeze(-2)
            eta = eta + (w * zr)[..., None] * g
        Pv = torch.linalg.inv(Lam)
        x[..., vi] = (Pv @ eta.unsqueeze(-1)).squeeze(-1)
        P = base_P.expand(B, S, M, n, n).clone()
        pt, vt = torch.tensor(pi, device=P.device), torch.tensor(vi, device=P.device)
        P[..., pt[:, None], pt] = Pp
        P[..., vt[:, None], vt] = Pv
        x = torch.where(real[..., None], x, park)
        P = torch.where(real[..., None, None], P, torch.eye(n, dtype=P.dtype, device=P.device))
        return Gaussian(x, P), real

    return seed


class BPTracks(TableTracks):
    """The BP tracker's :class:`~.roles.TrackManagement` (module docstring): the tracks in a
    :class:`~.management.TrackTable` with BP's existence, the undetected targets' mass
    ``undetected (B,)``, confirmation and deletion by existence. ``initiator`` starts tentative
    tracks where the association births none (no azimuth; None where it does), from the
    detections no track explains, with deviations ``other_sd (n,)`` of the entries it does not fix."""

    def __init__(self, settings: BPSettings, model: MeasurementModel, n: int, initiator: Initiator | None = None,
                 other_sd: torch.Tensor | None = None, dtype=torch.float64):
        self.s, self.model, self.n, self.initiator, self.other_sd, self.dtype = settings, model, n, initiator, other_sd, dtype
        self.started = None

    def begin(self, B: int, K: int, F: torch.Tensor | None = None, Q: torch.Tensor | None = None) -> None:
        device = None if F is None else F.device
        self.start_table(B, K, self.model, self.n, self.dtype, device)
        if self.initiator is not None:
            self.initiator.begin(B, F, Q)
        self.undetected = torch.full((B,), float(self.s.initial_targets), dtype=self.dtype, device=device)

    def predicted(self, k: int) -> None:
        self.predict_table(self.s.survival)
        self.undetected = self.s.survival * self.undetected + self.s.birth_rate

    def updated(self, k: int, step: BPStep, z: torch.Tensor, valid: torch.Tensor) -> None:
        table, s = self.table, self.s
        before = table.active
        C = before.shape[1]
        post = step.posterior
        table.g = Gaussian(post.x[:, :C], post.P[:, :C])
        table.existence = torch.where(before, step.existence[:, :C], table.existence)
        if step.born is not None:
            self.undetected = step.undetected
            born = step.born[:, C:]
            if bool(born.any()):
                table.add(Gaussian(post.x[:, C:], post.P[:, C:]), born, step.existence[:, C:])
        elif self.initiator is not None:
            unused = valid & ~step.explained
            new = self.initiator.initiate(z, unused, self.model, self.n, self.other_sd)  # every scan (multi-scan)
            if bool(unused.any()):
                table.add(*new, s.initial_existence)
        table.confirm((table.status == TENTATIVE) & (table.existence >= s.confirm_existence))
        table.free(table.active & (table.existence < s.delete_existence))
        self.report.write(k, table, s.report_existence)
        C2 = table.active.shape[1]
        grown = torch.cat([before, before.new_zeros(before.shape[0], C2 - C)], 1)
        started = table.active & ~grown
        self.started = started if bool(started.any()) else None


def bp_tracker(scans: Scans, motion: KinematicModel, dt: float, q: float, model: MeasurementModel, R: torch.Tensor,
               settings: BPSettings, other_sd: torch.Tensor, velocity_sd_mps: float = 10.0,
               initiator: Initiator | None = None, routes: torch.Tensor | None = None,
               refiner: MessageRefiner | None = None) -> TrackReport:
    """The BP tracker (module docstring) on per-pair detection lists ``scans`` (``z (B, K, S, M,
    d)``) of ``model`` with noise ``R (S d, S d)``, the CV/CA prediction of ``motion`` over ``dt``
    with process noise ``q``. New potential targets are seeded one per detection where the
    detections measure azimuth (``velocity_sd_mps`` the velocity prior per axis), else by
    ``initiator``; ``other_sd (n,)`` the deviations of the state entries neither fixes.

    ``routes (L, S)`` bool: the scans are ``L`` lists pooled per receiver (pair ``s`` ends at the
    receiver of list ``l``; the illuminator of a detection unknown), which each pair reads in
    turn (:class:`~.bp_associator.BPAssociator`'s ``lists``); ``settings``' clutter is then a
    pooled list's, and the detections must measure azimuth. ``refiner``: NEBP's learned corrections
    of each list's association inputs (:mod:`.message_refiner`; per-pair lists only). Returns the
    confirmed tracks as reported at each scan."""
    seeding = "azimuth" in model.components
    lists = None
    if routes is None:
        check_scans(scans, model)
    else:
        lists = list_of_pairs(routes).tolist()
        if tuple(scans.z.shape[2:3]) != (routes.shape[0],) or scans.z.shape[-1] != len(model.components):
            raise ConfigError(f"pooled detections come in {scans.z.shape[2]} lists of {scans.z.shape[-1]} values; the "
                              f"routes name {routes.shape[0]} receivers and the model measures {len(model.components)}")
        if not seeding:
            raise ConfigError("BP reads lists pooled per receiver only where each pair measures azimuth (a detection "
                              f"seeds a target under each illuminator); the detections measure {list(model.components)}")
        check_scans(Scans(scans.z[:, :, lists], scans.valid[:, :, lists], scans.origin[:, :, lists]), model)  # each pair's view
    n = motion.dim_x
    dtype = scans.z.dtype
    s = settings
    tracks = BPTracks(s, model, n, None if seeding else initiator, other_sd, dtype)
    births = None
    if seeding:
        births = Births(lambda: tracks.undetected, s.pd, s.clutter_count,
                        one_detection_seed(model, n, other_sd, velocity_sd_mps, dtype), s.delete_existence)
    associator = BPAssociator(model, R, s.pd * s.gate_probability, s.clutter_density,
                              existence=lambda: tracks.table.existence, gate_probability=s.gate_probability,
                              iterations=s.iterations, tolerance=s.tolerance, births=births, lists=lists,
                              refiner=refiner)
    return run_tracker(scans, motion, dt, q, associator, tracks)
