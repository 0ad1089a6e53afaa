"""PMHT that starts, confirms and deletes its own tracks (:func:`managed_pmht`): the tracks of
:mod:`.management` in PMHT's sliding window (:mod:`.pmht`).

Shapes: ``B`` runs (``b`` in a chunk), ``K`` scans, ``W`` scans of a window, ``C`` track slots,
``S`` pairs, ``M`` detections per list, ``n`` state dimension.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from ..filters.gaussian import Gaussian, predict
from ..motion import KinematicModel
from ..simulation.detections import PooledScans, Scans
from .management import Management, TrackReport, TrackTable, parked_state
from .pmht import initial_covariances, initial_states, window_starts
from .pmht_em import em_step, window_evidence
from .pmht_model import AssociationLists, PMHTProblem, PMHTSettings, check_lists, problem


def managed_pmht(scans: Scans | PooledScans, motion: KinematicModel, dt: float, q, model, R: torch.Tensor,
                 settings: PMHTSettings, management: Management) -> TrackReport:
    """PMHT that starts, confirms and deletes its own tracks (:mod:`.management`), on per-pair
    lists (:class:`~pmsr_nn.simulation.detections.Scans`: each detection's illuminator known) or
    on lists pooled per receiver (:class:`~pmsr_nn.simulation.detections.PooledScans`: a
    single-frequency network, the illuminator unknown; PMHT-3D's E-step weighs every pair of the
    receiver, and the :class:`~.fix_initiator.FixInitiator` fixes each unused detection under every
    illuminator hypothesis, see its ``routes``).

    The tracks live in a :class:`~.management.TrackTable` whose Gaussians are the priors at the
    current window's first scan; EM runs on every slot (a free slot explains no detection). After
    EM on a window, each scan the window commits (hands on: the scans before the next window's
    first), in order:

    1. existence: predicted by ``survival``, then each pair's IPDA update with the ratio of
       :func:`~.pmht_em.window_evidence` (no gate: ``Pd Pg = Pd``);
    2. a track whose summed association weight at a pair is >= 0.5 was detected there; hit and
       miss, M-of-N confirmation and deletion as the table does;
    3. the confirmed tracks whose existence is >= ``report_existence`` are reported with their
       smoothed states at that scan;
    4. the detections whose total weight on the tracks is < 0.5 (explained mostly by clutter)
       start tentative tracks (the management's initiator, :mod:`.initiators`).

    A track started at scan ``k`` of the window takes part in it from ``k`` on: it explains no
    detection before ``k`` and its filter is the initiator's Gaussian at ``k`` (see
    :func:`~.pmht_em.em_step`). So that it explains its own later detections in the window (and starts no
    second track from them, and can be confirmed at ``k + 1``), EM is run again on the window
    with the new tracks and the committed scans go on from ``k + 1``; a track started at the last
    committed scan is only predicted into the next window. With ``e_step = "marginal"`` EM weighs
    each detection under the track's spread as in :func:`~.pmht.pmht`: the covariances start as
    the previous window's smoothed ones on the overlap, and a new track's as its initiator's
    covariance predicted from the scan it starts at. Returns the reported confirmed tracks
    (:class:`~.management.TrackReport`, ``(B, K, N, n)``), smoothed: not causal.
    """
    S = getattr(model, "n_pairs", 1)
    pooled = isinstance(scans, PooledScans)
    lists = AssociationLists.pooled(scans) if pooled else AssociationLists.per_pair(scans)
    check_lists(lists, None, S, motion.dim_x)
    management.check(model, "PMHT", pooled=pooled)
    routes = scans.routes if pooled else None
    B, K = lists.z.shape[:2]
    pr = problem(model, motion, dt, q, R, settings, lists.z.dtype, lists.z.device)
    starts = window_starts(K, settings)
    parts = [_managed_runs(pr, lists.take(slice(c0, min(B, c0 + settings.chunk_runs))), starts, management,
                           list(motion.pos_idx), routes) for c0 in range(0, B, settings.chunk_runs)]
    N = max(p.x.shape[2] for p in parts)
    cat = lambda name, fill: torch.cat([_pad_slots(getattr(p, name), N, fill) for p in parts], 0)
    return TrackReport(cat("x", math.nan), cat("P", 0.0), cat("exists", False), cat("existence", 0.0)).trimmed()


def _managed_runs(pr: PMHTProblem, lists: AssociationLists, starts: list[int], mg: Management,
                  pos: list[int], routes: torch.Tensor | None) -> TrackReport:
    """:func:`managed_pmht` on one chunk of ``b`` runs (``routes (L, S)``: the pooled lists'
    pairs, None: per-pair lists). Each run's EM is re-run only when that run started tracks, and
    stops on that run's own movement: a run's tracks do not depend on which other runs share its
    chunk."""
    b, K, L = lists.z.shape[:3]
    S = pr.pairs
    s, model, n, dtype = pr.settings, pr.model, pr.F.shape[0], lists.z.dtype
    table = TrackTable.empty(b, n, parked_state(model, n, dtype))
    report = TrackReport.empty(b, K, n, dtype)
    X = Pm = None
    marginal = s.e_step == "marginal"
    fresh = torch.ones(b, 0, dtype=torch.bool)  # slots without smoothed covariances from the last window
    for i, a in enumerate(starts):
        W = min(s.window, K - a)
        h = (starts[i + 1] if i + 1 < len(starts) else K) - a  # scans this window commits
        win = lists.take(slice(None), slice(a, a + W))
        C = table.g.x.shape[1]
        shift = a - starts[i - 1] if i else 0
        X = initial_states(pr, table.g, X, shift, W, b, C)
        born = torch.full((b, C), -1, dtype=torch.int64)  # scan of the window a track started at (-1: before)
        if marginal:
            Pm = initial_covariances(pr, table.g, Pm, shift, W, b, C)
            fresh = _pad_slots(fresh, C, True, 1)
            Pm = _started_covariances(pr, Pm, fresh, torch.zeros_like(born), table.g.P)
        fit = _WindowFit.empty(X, L, lists.z.shape[3], S)
        redo = torch.ones(b, dtype=torch.bool)  # runs whose EM must run (again) before scan k
        late = torch.zeros(b, C, dtype=torch.bool)  # tracks started at the last committed scan
        for k in range(h):
            if bool(redo.any()):
                C = table.g.x.shape[1]
                born = torch.where(table.active, born, -1)
                alive = table.active[:, None, :] & (born[:, None, :] <= torch.arange(W)[None, :, None])
                # table.g: the prior at the window's first scan of a track that was there, the
                # initiator's Gaussian of one started inside it (the smoother's start at its scan)
                rows = redo.nonzero()[:, 0]
                fit = fit.padded(C).put(rows, _window_em(pr, X[rows], Gaussian(table.g.x[rows], table.g.P[rows]),
                                                         win.take(rows), h, alive[rows], born[rows], pos,
                                                         None if Pm is None else Pm[rows]))
                X = fit.X
                if marginal:
                    Pm = fit.P.clone()
            if a + k > 0:
                table.predict_existence(mg.survival)
            for j in range(S):
                table.update_existence(fit.ratio[:, k, :, j], s.pd)
            table.record((fit.pair_w[:, k] >= 0.5).sum(-1), mg.hit_pairs)
            table.manage(mg.confirmer, mg.deleter, pos)
            shown = replace(table, g=Gaussian(X[:, k], fit.P[:, k]))  # the smoothed states at this scan
            report.write(a + k, shown, mg.report_existence)
            unused = win.valid[:, k] & (fit.target_w[:, k] < 0.5)  # (b, L, M)
            before = table.active
            if bool(unused.any()):
                where = {} if routes is None else {"routes": routes}
                table.add(*mg.initiator.initiate(win.z[:, k], unused, model, n, mg.other_sd, **where),
                          mg.initial_existence)
            C = table.g.x.shape[1]
            late = table.active & ~_pad_slots(before, C, False, 1)
            redo = late.any(-1)
            if bool(redo.any()):
                born = torch.where(late, k, _pad_slots(born, C, -1, 1))
                X = _started_rows(pr, _pad_slots(X, C, 0.0), late, born, table.g.x)
                if marginal:
                    Pm = _started_covariances(pr, _pad_slots(Pm, C, 0.0), late, born, table.g.P)
        # hand on: the last EM's forward prediction at the next window's first scan; a track
        # started at the last committed scan (after that EM) predicted from its initiator
        fit = fit.padded(table.g.x.shape[1])
        step = predict(table.g, pr.F, pr.Q)
        table.g = Gaussian(torch.where(late[..., None], step.x, fit.handed.x),
                           torch.where(late[..., None, None], step.P, fit.handed.P))
        table.free(~table.active)  # keep free slots parked
        if marginal:  # the smoothed covariances the next window starts from; late tracks have none
            Pm = fit.P
            fresh = late.clone()
    return report


@dataclass
class _WindowFit:
    """What EM on a window gives each run: states ``X (b, W, C, n)``, covariances ``P``, the
    forward prediction handed to the next window ``(b, C, n)`` and :func:`~.pmht_em.window_evidence`."""

    X: torch.Tensor
    P: torch.Tensor
    handed: Gaussian
    pair_w: torch.Tensor
    ratio: torch.Tensor
    target_w: torch.Tensor

    @classmethod
    def empty(cls, X: torch.Tensor, L: int, M: int, S: int) -> "_WindowFit":
        """Nothing fitted yet: ``L`` lists of ``M`` detections, ``S`` pairs."""
        b, W, C, n = X.shape
        z = X.new_zeros
        return cls(X, z(b, W, C, n, n), Gaussian(z(b, C, n), z(b, C, n, n)), z(b, W, C, S), z(b, W, C, S),
                   z(b, W, L, M))

    def padded(self, C: int) -> "_WindowFit":
        """Slots up to ``C``; the new slots are free (no weight, no evidence)."""
        return _WindowFit(_pad_slots(self.X, C, 0.0), _pad_slots(self.P, C, 0.0),
                          Gaussian(_pad_slots(self.handed.x, C, 0.0, 1), _pad_slots(self.handed.P, C, 0.0, 1)),
                          _pad_slots(self.pair_w, C, 0.0), _pad_slots(self.ratio, C, 0.0), self.target_w)

    def put(self, rows: torch.Tensor, part: "_WindowFit") -> "_WindowFit":
        """A copy with the runs ``rows`` replaced by ``part``."""
        def put(full, new):
            out = full.clone()
            out[rows] = new
            return out
        return _WindowFit(put(self.X, part.X), put(self.P, part.P),
                          Gaussian(put(self.handed.x, part.handed.x), put(self.handed.P, part.handed.P)),
                          put(self.pair_w, part.pair_w), put(self.ratio, part.ratio), put(self.target_w, part.target_w))


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
    todo = torch.arange(b)
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


def _pad_slots(t: torch.Tensor, C: int, fill, dim: int = 2) -> torch.Tensor:
    """``t`` with its slot axis ``dim`` padded to ``C`` with ``fill``."""
    extra = C - t.shape[dim]
    if extra <= 0:
        return t
    shape = list(t.shape)
    shape[dim] = extra
    return torch.cat([t, t.new_full(shape, fill)], dim)


def _started_rows(pr: PMHTProblem, X: torch.Tensor, rows: torch.Tensor, born: torch.Tensor,
                  x0: torch.Tensor) -> torch.Tensor:
    """EM's starting states ``X (b, W, C, n)`` with the tracks ``rows (b, C)`` started inside the
    window at scan ``born (b, C)`` set to their initiator mean ``x0 (b, C, n)`` there, its CV
    predictions after and the same mean before (where they explain nothing)."""
    W = X.shape[1]
    powers = torch.stack([torch.linalg.matrix_power(pr.F, k) for k in range(W)])  # (W, n, n)
    steps = (torch.arange(W)[None, :, None] - born[:, None, :]).clamp(0, W - 1)  # (b, W, C)
    xk = (powers[steps] @ x0[:, None, :, :, None]).squeeze(-1)
    return torch.where(rows[:, None, :, None], xk, X)


def _started_covariances(pr: PMHTProblem, P: torch.Tensor, rows: torch.Tensor, born: torch.Tensor,
                         P0: torch.Tensor) -> torch.Tensor:
    """The marginal E-step's covariances ``P (b, W, C, n, n)`` with the tracks ``rows (b, C)``
    started at scan ``born (b, C)`` set to ``P0 (b, C, n, n)`` there, predicted (``F P F^T + Q``)
    after and the same before (where they explain nothing)."""
    b, W, C = P.shape[:3]
    seq = initial_covariances(pr, Gaussian(P0[..., 0], P0), None, 0, W, b, C)  # (b, W, C, n, n): j steps after the start
    steps = (torch.arange(W)[None, :, None] - born[:, None, :]).clamp(0, W - 1)  # (b, W, C)
    Pk = seq.gather(1, steps[..., None, None].expand(*steps.shape, *P.shape[-2:]))
    return torch.where(rows[:, None, :, None, None], Pk, P)
