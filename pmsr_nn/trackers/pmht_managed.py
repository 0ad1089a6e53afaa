"""PMHT that starts, confirms and deletes its own tracks (:func:`managed_pmht`): PMHT's sliding
window EM (:mod:`.pmht`) as the associator of the one tracker loop, with the own-track
management of :mod:`.own_tracks`.

Shapes: ``B`` runs (``b`` in a chunk), ``K`` scans, ``W`` scans of a window, ``C`` track slots,
``S`` pairs, ``M`` detections per list, ``n`` state dimension.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..filters.gaussian import Gaussian, predict
from ..motion import KinematicModel
from ..simulation.detections import PooledScans, Scans, pad_axis
from .loop import run_tracker
from .management import Management, TrackReport
from .own_tracks import OwnTracks
from .pmht import initial_covariances, initial_states, window_starts
from .pmht_em import em_step, window_evidence
from .pmht_model import AssociationLists, PMHTProblem, PMHTSettings, check_lists, problem
from .roles import Associator, AssociationStep


def managed_pmht(scans: Scans | PooledScans, motion: KinematicModel, dt: float, q, model, R: torch.Tensor,
                 settings: PMHTSettings, management: Management) -> TrackReport:
    """PMHT that starts, confirms and deletes its own tracks, on per-pair lists
    (:class:`~pmsr_nn.simulation.detections.Scans`: each detection's illuminator known) or on lists
    pooled per receiver (:class:`~pmsr_nn.simulation.detections.PooledScans`: a single-frequency
    network, the illuminator unknown; PMHT-3D's E-step weighs every pair of the receiver, and the
    :class:`~.fix_initiator.FixInitiator` fixes each unused detection under every illuminator
    hypothesis, see its ``routes``).

    An assembly on the one tracker loop: :class:`PMHTWindows` (the window EM as the associator)
    with :class:`~.own_tracks.OwnTracks`, chunk by chunk of ``settings.chunk_runs`` runs. Each
    scan a window commits (hands on: the scans before the next window's first), in order:

    1. existence: predicted by ``survival``, then each pair's IPDA update with the ratio of
       :func:`~.pmht_em.window_evidence` (no gate: ``Pd Pg = Pd``), or its shared ratio with the
       management's ``shared_existence``;
    2. a track whose summed association weight at a pair is >= 0.5 was detected there; hit and
       miss, M-of-N confirmation and deletion as the table does;
    3. where the management has a coalescence test, confirmed tracks whose smoothed states
       coalesce are merged; the confirmed tracks whose existence is >= ``report_existence`` are
       reported with their smoothed states at that scan;
    4. the detections whose total weight on the tracks is < 0.5 (explained mostly by clutter)
       start tentative tracks (the management's initiator, :mod:`.initiators`).

    Returns the reported confirmed tracks (:class:`~.management.TrackReport`, ``(B, K, N, n)``),
    smoothed: not causal.
    """
    S = getattr(model, "n_pairs", 1)
    pooled = isinstance(scans, PooledScans)
    lists = AssociationLists.pooled(scans) if pooled else AssociationLists.per_pair(scans)
    check_lists(lists, None, S, motion.dim_x)
    management.check(model, "PMHT", pooled=pooled)
    initiate = {"routes": scans.routes} if pooled else {}
    B, K = lists.z.shape[:2]
    pr = problem(model, motion, dt, q, R, settings, lists.z.dtype, lists.z.device)
    starts = window_starts(K, settings)
    parts = []
    for c0 in range(0, B, settings.chunk_runs):
        chunk = lists.take(slice(c0, min(B, c0 + settings.chunk_runs)))
        tracks = OwnTracks(management, model, motion.dim_x, settings.pd, lists.z.dtype, **initiate)
        parts.append(run_tracker(chunk, motion, dt, q, PMHTWindows(pr, chunk, starts, list(motion.pos_idx)), tracks))
    N = max(p.x.shape[2] for p in parts)
    cat = lambda name, fill: torch.cat([pad_axis(getattr(p, name), N, fill, 2) for p in parts], 0)
    return TrackReport(cat("x", math.nan), cat("P", 0.0), cat("exists", False), cat("existence", 0.0)).trimmed()


class PMHTWindows(Associator):
    """PMHT's sliding-window EM as the associator of :func:`~.loop.run_tracker` (``b`` runs of
    ``lists``, window starts ``starts``, ``pos`` the position entries of the state).

    The tracks' Gaussians are the priors at the current window's first scan; EM runs on every slot
    (a free slot explains no detection), and each run's EM is re-run only when that run started
    tracks, stopping on that run's own movement: a run's tracks do not depend on which other runs
    share its chunk. :meth:`predict` leaves the tracks alone but at a window's first scan, where it
    hands on the last EM's forward prediction (a track started at the last committed scan, after
    that EM, is predicted from its initiator). A track started at scan ``k`` of a window takes part
    in it from ``k`` on: it explains no detection before ``k`` and its filter is the initiator's
    Gaussian at ``k`` (see :func:`~.pmht_em.em_step`); so that it explains its own later
    detections in the window (and starts no second track from them, and can be confirmed at
    ``k + 1``), EM is run again on the window with the new tracks. With ``e_step = "marginal"`` EM
    weighs each detection under the track's spread as in :func:`~.pmht.pmht`: the covariances
    start as the previous window's smoothed ones on the overlap, and a new track's as its
    initiator's covariance predicted from the scan it starts at."""

    def __init__(self, pr: PMHTProblem, lists: AssociationLists, starts: list[int], pos: list[int]):
        self.pr, self.lists, self.starts, self.pos = pr, lists, starts, pos
        self.marginal = pr.settings.e_step == "marginal"
        b = lists.z.shape[0]
        self.X = self.Pm = None
        dev = lists.z.device
        # slots without smoothed covariances from the last window
        self.fresh = torch.ones(b, 0, dtype=torch.bool, device=dev)
        self.window, self.k = -1, -1
        self.late = torch.zeros(b, 0, dtype=torch.bool, device=dev)  # tracks started at the last committed scan

    def predict(self, g: Gaussian, k: int, F: torch.Tensor, Q: torch.Tensor) -> Gaussian:
        if k not in self.starts:
            return g
        # hand on: the last EM's forward prediction at the next window's first scan; a track
        # started at the last committed scan (after that EM) predicted from its initiator
        fit = self.fit.padded(g.x.shape[1])
        step = predict(g, self.pr.F, self.pr.Q)
        late = pad_axis(self.late, g.x.shape[1], False, 1)
        if self.marginal:  # the smoothed covariances the next window starts from; late tracks have none
            self.Pm, self.fresh = fit.P, late.clone()
        return Gaussian(torch.where(late[..., None], step.x, fit.handed.x),
                        torch.where(late[..., None, None], step.P, fit.handed.P))

    def _open(self, g: Gaussian) -> None:
        """Window ``self.window`` from its first scan: EM's starting states and covariances."""
        pr, i = self.pr, self.window
        a = self.starts[i]
        K = self.lists.z.shape[1]
        b, C = g.x.shape[:2]
        self.W = min(pr.settings.window, K - a)
        self.h = (self.starts[i + 1] if i + 1 < len(self.starts) else K) - a  # scans this window commits
        self.win = self.lists.take(slice(None), slice(a, a + self.W))
        shift = a - self.starts[i - 1] if i else 0
        self.X = initial_states(pr, g, self.X, shift, self.W, b, C)
        dev = g.x.device
        # scan of the window a track started at (-1: before)
        self.born = torch.full((b, C), -1, dtype=torch.int64, device=dev)
        if self.marginal:
            Pm = initial_covariances(pr, g, self.Pm, shift, self.W, b, C)
            self.fresh = pad_axis(self.fresh, C, True, 1)
            self.Pm = _started_covariances(pr, Pm, self.fresh, torch.zeros_like(self.born), g.P)
        self.fit = _WindowFit.empty(self.X, self.lists.z.shape[2], self.lists.z.shape[3], pr.pairs)
        self.redo = torch.ones(b, dtype=torch.bool, device=dev)  # runs whose EM must run (again) before this scan
        self.late = torch.zeros(b, C, dtype=torch.bool, device=dev)

    def associate(self, g: Gaussian, z: torch.Tensor, valid: torch.Tensor,
                  associating: torch.Tensor | None) -> AssociationStep:
        """Scan ``k`` of the window: EM (again) for the runs that need it, then that scan's
        evidence. ``associating`` is every active slot (own tracks)."""
        self.k += 1
        if self.window + 1 < len(self.starts) and self.k == self.starts[self.window + 1]:
            self.window += 1
            self._open(g)
        kk = self.k - self.starts[self.window]
        if bool(self.redo.any()):
            C = g.x.shape[1]
            self.born = torch.where(associating, self.born, -1)
            scans = torch.arange(self.W, device=g.x.device)
            alive = associating[:, None, :] & (self.born[:, None, :] <= scans[None, :, None])
            # g: the prior at the window's first scan of a track that was there, the initiator's
            # Gaussian of one started inside it (the smoother's start at its scan)
            rows = self.redo.nonzero()[:, 0]
            self.fit = self.fit.padded(C).put(rows, _window_em(
                self.pr, self.X[rows], Gaussian(g.x[rows], g.P[rows]), self.win.take(rows), self.h, alive[rows],
                self.born[rows], self.pos, None if self.Pm is None else self.Pm[rows]))
            self.X = self.fit.X
            if self.marginal:
                self.Pm = self.fit.P.clone()
        fit = self.fit
        return AssociationStep(g, (fit.pair_w[:, kk] >= 0.5).sum(-1), fit.ratio[:, kk], ~(fit.target_w[:, kk] < 0.5),
                               reported=Gaussian(self.X[:, kk], fit.P[:, kk]), taken=fit.target_w[:, kk],
                               shared_ratio=fit.shared[:, kk])

    def tracks_started(self, started: torch.Tensor | None, g: Gaussian) -> None:
        C = g.x.shape[1]
        self.late = torch.zeros(g.x.shape[:2], dtype=torch.bool, device=g.x.device) if started is None else started
        self.redo = self.late.any(-1)
        if bool(self.redo.any()):
            kk = self.k - self.starts[self.window]
            self.born = torch.where(self.late, kk, pad_axis(self.born, C, -1, 1))
            self.X = _started_rows(self.pr, pad_axis(self.X, C, 0.0, 2), self.late, self.born, g.x)
            if self.marginal:
                self.Pm = _started_covariances(self.pr, pad_axis(self.Pm, C, 0.0, 2), self.late, self.born, g.P)


@dataclass
class _WindowFit:
    """What EM on a window gives each run: states ``X (b, W, C, n)``, covariances ``P``, the
    forward prediction handed to the next window ``(b, C, n)`` and :func:`~.pmht_em.window_evidence`
    (``shared``: its shared ratio)."""

    X: torch.Tensor
    P: torch.Tensor
    handed: Gaussian
    pair_w: torch.Tensor
    ratio: torch.Tensor
    target_w: torch.Tensor
    shared: torch.Tensor

    @classmethod
    def empty(cls, X: torch.Tensor, L: int, M: int, S: int) -> "_WindowFit":
        """Nothing fitted yet: ``L`` lists of ``M`` detections, ``S`` pairs."""
        b, W, C, n = X.shape
        z = X.new_zeros
        return cls(X, z(b, W, C, n, n), Gaussian(z(b, C, n), z(b, C, n, n)), z(b, W, C, S), z(b, W, C, S),
                   z(b, W, L, M), z(b, W, C, S))

    def padded(self, C: int) -> "_WindowFit":
        """Slots up to ``C``; the new slots are free (no weight, no evidence)."""
        return _WindowFit(pad_axis(self.X, C, 0.0, 2), pad_axis(self.P, C, 0.0, 2),
                          Gaussian(pad_axis(self.handed.x, C, 0.0, 1), pad_axis(self.handed.P, C, 0.0, 1)),
                          pad_axis(self.pair_w, C, 0.0, 2), pad_axis(self.ratio, C, 0.0, 2), self.target_w,
                          pad_axis(self.shared, C, 0.0, 2))

    def put(self, rows: torch.Tensor, part: "_WindowFit") -> "_WindowFit":
        """A copy with the runs ``rows`` replaced by ``part``."""
        def put(full, new):
            out = full.clone()
            out[rows] = new
            return out
        return _WindowFit(put(self.X, part.X), put(self.P, part.P),
                          Gaussian(put(self.handed.x, part.handed.x), put(self.handed.P, part.handed.P)),
                          put(self.pair_w, part.pair_w), put(self.ratio, part.ratio), put(self.target_w, part.target_w),
                          put(self.shared, part.shared))


def _window_em(pr: PMHTProblem, X: torch.Tensor, prior: Gaussian, win: AssociationLists, h: int,
               alive: torch.Tensor, born: torch.Tensor, pos: list[int], P: torch.Tensor | None = None) -> _WindowFit:
    """EM of :func:`managed_pmht` on a window for ``b`` runs from states ``X (b, W, C, n)`` and
    ``prior`` ``(b, C, n)``: ``em_iterations`` per run, fewer for a run whose positions all move
    less than ``tolerance_m``. ``P (b, W, C, n, n)``: the covariances of ``X`` for the marginal
    E-step (None: the point E-step)."""
    b, W, C, n = X.shape
    s = pr.settings
    marginal = P is not None
    X, P = X.clone(), (P.clone() if marginal else X.new_zeros(b, W, C, n, n))
    hx, hP = X.new_zeros(b, C, n), X.new_zeros(b, C, n, n)
    todo = torch.arange(b, device=X.device)
    for it in range(s.em_iterations):
        g = Gaussian(prior.x[todo].reshape(-1, n), prior.P[todo].reshape(-1, n, n))
        X_new, P_new, handed, _ = em_step(pr, X[todo], g, win.take(todo), s.inflation(it), h, alive[todo],
                                          born[todo], g, P=P[todo] if marginal else None)
        moved = (X_new - X[todo])[..., pos].norm(dim=-1).flatten(1).amax(1)
        X[todo], P[todo] = X_new, P_new
        hx[todo], hP[todo] = handed.x.reshape(-1, C, n), handed.P.reshape(-1, C, n, n)
        if s.tolerance_m > 0:
            todo = todo[moved >= s.tolerance_m]
            if len(todo) == 0:
                break
    return _WindowFit(X, P, Gaussian(hx, hP), *window_evidence(pr, X, win, alive))


def _started_rows(pr: PMHTProblem, X: torch.Tensor, rows: torch.Tensor, born: torch.Tensor,
                  x0: torch.Tensor) -> torch.Tensor:
    """EM's starting states ``X (b, W, C, n)`` with the tracks ``rows (b, C)`` started inside the
    window at scan ``born (b, C)`` set to their initiator mean ``x0 (b, C, n)`` there, its CV
    predictions after and the same mean before (where they explain nothing)."""
    W = X.shape[1]
    powers = torch.stack([torch.linalg.matrix_power(pr.F, k) for k in range(W)])  # (W, n, n)
    scans = torch.arange(W, device=born.device)
    steps = (scans[None, :, None] - born[:, None, :]).clamp(0, W - 1)  # (b, W, C)
    xk = (powers[steps] @ x0[:, None, :, :, None]).squeeze(-1)
    return torch.where(rows[:, None, :, None], xk, X)


def _started_covariances(pr: PMHTProblem, P: torch.Tensor, rows: torch.Tensor, born: torch.Tensor,
                         P0: torch.Tensor) -> torch.Tensor:
    """The marginal E-step's covariances ``P (b, W, C, n, n)`` with the tracks ``rows (b, C)``
    started at scan ``born (b, C)`` set to ``P0 (b, C, n, n)`` there, predicted (``F P F^T + Q``)
    after and the same before (where they explain nothing)."""
    b, W, C = P.shape[:3]
    seq = initial_covariances(pr, Gaussian(P0[..., 0], P0), None, 0, W, b, C)  # (b, W, C, n, n): j steps after the start
    scans = torch.arange(W, device=born.device)
    steps = (scans[None, :, None] - born[:, None, :]).clamp(0, W - 1)  # (b, W, C)
    Pk = seq.gather(1, steps[..., None, None].expand(*steps.shape, *P.shape[-2:]))
    return torch.where(rows[:, None, :, None, None], Pk, P)
