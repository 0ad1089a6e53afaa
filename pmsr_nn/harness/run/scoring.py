"""Per-block sums of one method's estimates against the truth: what :mod:`.runner` keeps.

Everything here is summed over the runs of a block (the Monte Carlo dimension), so that the
figures of a scenario are sums of blocks reduced in block order (shards merge bit for bit).
Shapes: ``K`` scans, ``N`` targets (= track slots of a labelled tracker), ``B`` runs.

Point metrics (every method, every case), on the (run, scan, target) entries where the target
lives and its track exists:

* ``pos`` / ``vel`` ``(K, N)``: summed squared position / velocity error (m^2, m^2/s^2), ``count``
  ``(K, N)`` how many runs entered them;
* ``nees`` ``(K, N)``: summed NEES over the full state / its dimension (NaN: no covariances);
* ``run_mse`` ``(B, N)``: per run and target, the mean squared position error over its scored scans.

Multi-target metrics (cases with more than one target, and every tracker that starts its own
tracks), from the labelled estimates as sets: OSPA and GOSPA (split into localisation, missed and
false parts) per scan, the cardinality error, per-target squared error after the best fixed
assignment of track labels to targets over the run (``assigned_pos``, ``assigned_count``), label
switches per target, trajectory GOSPA with a switching cost (:func:`trajectory_sums`; labelled
tracks only) and the swaps of the S-MSJPDA study (at the last scan, a track nearer another
target than its own; paired slots only). A kind's own figures (the paper's track-loss rule, a
PHD's integral, the per-frame figures of track-before-detect) are the sums of the metrics it
declares (:mod:`pmsr_nn.methods.kind_metrics`). Label switches, identity switches (a target's track changing from the last one
it had, also across scans without one) and the track-level sums (:func:`track_sums`) come from
the persistent (CLEAR MOT) mapping of :func:`track_mapping`: a track stays on its target while it
is within the cut-off, so two tracks that each follow their own target through a crossing are not
counted as switching there (the per-scan assignment swaps them wherever that costs a little less).

Estimates whose slots are tracks the tracker started (``paired=False``) enter the point metrics
through their *matched view* (:func:`matched_view`): at each scan each target's track is the one
the per-scan OSPA/GOSPA assignment gives it, so ``pos`` is the squared error of matched tracks
and ``count`` how often a target had one.
"""

from __future__ import annotations

import numpy as np
import torch

from ...metrics import (SetScores, identity_switches, label_switches, labelled_assignment, matched_tracks,
                       normalised_nees, persistent_assignment, set_scores, squared_error, track_scores,
                       trajectory_gospa)
from ...methods.kind_metrics import PER_RUN_SUMS
from ...simulation.products import Truth
from ...trackers.base import Estimates

PER_RUN = ("run_mse", "gospa_run", "ospa_run", "tgospa_run")
"""The harness's quantities kept per run (concatenated over blocks); every other one is summed per block."""


def per_run(q: str) -> bool:
    """Whether quantity ``q`` is kept per run: one of :data:`PER_RUN` or of a kind's metric's
    (:data:`~pmsr_nn.methods.kind_metrics.PER_RUN_SUMS`)."""
    return q in PER_RUN or q in PER_RUN_SUMS


def _masked_sum(values: torch.Tensor, mask: torch.Tensor) -> np.ndarray:
    zero = torch.zeros((), dtype=values.dtype)
    return torch.where(mask, values, zero).sum(0).numpy()


def point_sums(est: Estimates, truth: Truth, scored: torch.Tensor, pos: list[int], vel: list[int]) -> dict[str, np.ndarray]:
    """``pos``, ``vel``, ``count``, ``nees`` and ``run_mse`` (module docstring); ``scored (K, N)``
    marks the scans of each target that enter ``run_mse`` (after its warm-up); ``pos`` / ``vel``
    are the state's position / velocity columns."""
    live = est.exists & truth.alive  # (B, K, N)
    se_p = squared_error(est.x, truth.x, pos)
    se_v = squared_error(est.x, truth.x, vel)
    if est.P is not None:
        nees = normalised_nees(est.x, est.P, truth.x)
    else:
        nees = torch.full_like(se_p, float("nan"))
    if se_p.shape[-1] == 1 and bool(live.all()):  # one target, always tracked: the plain mean of its scored scans
        run_mse = se_p[:, scored[:, 0], 0].mean(1, keepdim=True)
    else:
        mask = scored & live
        run_mse = torch.where(mask, se_p, torch.zeros((), dtype=se_p.dtype)).sum(1) / mask.sum(1).clamp(min=1)
    return {"pos": _masked_sum(se_p, live), "vel": _masked_sum(se_v, live),
            "count": live.sum(0).to(torch.float64).numpy(),
            "nees": torch.where(live, nees, torch.zeros((), dtype=nees.dtype)).sum(0).numpy() if est.P is not None
            else np.full(tuple(live.shape[1:]), np.nan),
            "run_mse": run_mse.numpy()}


def swaps(est: Estimates, truth: Truth, pos: list[int]) -> dict[str, np.ndarray]:
    """``swap (N,)``: runs in which, at the last scan, target ``t``'s track is nearer another living
    target's truth than its own; ``swap_n (N,)``: runs in which target ``t`` and its track exist then."""
    alive = truth.alive[-1]  # (N,)
    e, t = est.x[:, -1][..., pos], truth.x[:, -1][..., pos]  # (B, N, 2)
    d = torch.cdist(torch.nan_to_num(e), torch.nan_to_num(t))
    d = torch.where(alive[None, None, :], d, torch.full_like(d, float("inf")))
    ok = est.exists[:, -1] & alive  # (B, N)
    swapped = ok & (d.argmin(-1) != torch.arange(est.x.shape[2]))
    return {"swap": swapped.sum(0).to(torch.float64).numpy(), "swap_n": ok.sum(0).to(torch.float64).numpy()}


def per_scan_sets(est: Estimates, truth: Truth, pos: list[int], c: float, p: float) -> SetScores:
    """OSPA, GOSPA and their per-scan assignment ``(B, K, M)`` of the reported tracks to the
    living targets (position columns ``pos``, cut-off ``c``, order ``p``)."""
    B, K, M = est.exists.shape
    N = truth.x.shape[2]
    return set_scores(est.x[..., pos], est.exists, truth.x[..., pos], truth.alive.expand(B, K, N), c, p)


def track_mapping(est: Estimates, truth: Truth, pos: list[int], c: float, p: float) -> torch.Tensor:
    """``(B, K, M)``: the persistent (CLEAR MOT) mapping of tracks to targets
    (:func:`~pmsr_nn.metrics.persistent_assignment`) that the track-level figures (tracks per
    target, label switches, fragmentations, first track, loss) are counted on; the set figures
    and the matched tracks' errors use each scan's optimal assignment."""
    B, K, _ = est.exists.shape
    N = truth.x.shape[2]
    return persistent_assignment(est.x[..., pos], est.exists, truth.x[..., pos], truth.alive.expand(B, K, N), c, p)


def matched_view(est: Estimates, assignment: torch.Tensor, N: int) -> Estimates:
    """Paired estimates ``(B, K, N)`` of unpaired tracks: each target's matched track per scan."""
    x, P, matched = matched_tracks(assignment, est.x, est.P, N)
    return Estimates(x, matched, P, paired=True)


def track_sums(assignment: torch.Tensor, exists: torch.Tensor, truth: Truth) -> dict[str, np.ndarray]:
    """Track-level sums over the runs (:func:`~pmsr_nn.metrics.track_scores` over each target's
    whole life): ``tracks_per_target``, ``missed_scans``, ``alive_scans``, ``lost_tracks``,
    ``fragmentations`` ``(N,)``, ``first_track_scans`` / ``first_track_count`` ``(N,)`` (sum and
    count of the scans from birth to the first matched track, over runs that had one),
    ``false_tracks`` and ``runs_without_tracks`` (scalars: runs in which the row reported no track
    at any scan though some target lived, e.g. a tracker whose existence never reaches its
    reporting threshold)."""
    B, K, N = truth.x.shape[:3]
    alive = truth.alive.expand(B, K, N)
    silent = ~exists.flatten(1).any(1) & alive.flatten(1).any(1)  # (B,)
    ts = track_scores(assignment, exists, alive)
    first = ts.scans_to_first_track
    found = torch.isfinite(first)
    as64 = lambda t: t.to(torch.float64).sum(0).numpy()
    return {"tracks_per_target": as64(ts.tracks_per_target), "missed_scans": as64(ts.missed_scans),
            "alive_scans": as64(ts.alive_scans), "lost_tracks": as64(ts.lost), "fragmentations": as64(ts.fragmentations),
            "first_track_scans": as64(torch.where(found, first, torch.zeros((), dtype=first.dtype))),
            "first_track_count": as64(found), "false_tracks": np.asarray(float(ts.false_tracks.sum())),
            "runs_without_tracks": np.asarray(float(silent.sum()))}


def gospa_per_run(sc: SetScores, scored_scans: torch.Tensor) -> dict[str, np.ndarray]:
    """``gospa_run (B,)``: each run's mean over the scored scans ``(K,)`` of GOSPA^p (m^p);
    ``ospa_run (B,)``: of OSPA (m); what the Monte Carlo errors of the GOSPA and OSPA cells are
    computed from."""
    g = sc.gospa
    per_scan = g.localisation + g.missed + g.false  # (B, K)
    return {"gospa_run": per_scan[:, scored_scans].mean(1).numpy(), "ospa_run": sc.ospa[:, scored_scans].mean(1).numpy()}


def trajectory_sums(est: Estimates, truth: Truth, pos: list[int], c: float, p: float,
                    scans: torch.Tensor) -> dict[str, np.ndarray]:
    """Trajectory GOSPA (:func:`~pmsr_nn.metrics.trajectory_gospa`, alpha = 2, switching cost
    ``gamma = c``, its LP relaxation) of each run's tracks over the scans ``scans (K,)`` (the set
    scans), divided by their number so that it reads like GOSPA^p per scan (m^p): ``tgospa_run
    (B,)`` per run; summed over the runs ``tgospa_loc``, ``tgospa_missed``, ``tgospa_false``,
    ``tgospa_switching`` (its parts, m^p per scan), ``tgospa_switches`` (a half switch counts 1/2)
    and ``tgospa_integral`` (runs whose LP solution is integral: there it is the integer
    programme's value, the metric itself). A track whose position is not finite at a scan (a
    diverged filter) counts as absent there."""
    B, K, M = est.exists.shape
    N = truth.x.shape[2]
    e, t = est.x[:, scans][..., pos], truth.x[:, scans][..., pos]
    exists = est.exists[:, scans] & torch.isfinite(e).all(-1)
    tg = trajectory_gospa(e, exists, t, truth.alive.expand(B, K, N)[:, scans], c, p, c, integer=False)
    n = max(int(scans.sum()), 1)
    f = lambda v: np.asarray(float(v.sum()) / n)
    return {"tgospa_run": (tg.total ** p / n).numpy(), "tgospa_loc": f(tg.localisation), "tgospa_missed": f(tg.missed),
            "tgospa_false": f(tg.false), "tgospa_switching": f(tg.switching),
            "tgospa_switches": np.asarray(float(tg.n_switches.sum())),
            "tgospa_integral": np.asarray(float(tg.integral.sum()))}


def set_sums(est: Estimates, truth: Truth, pos: list[int], c: float, p: float,
             sc: SetScores | None = None, mapping: torch.Tensor | None = None) -> dict[str, np.ndarray]:
    """Multi-target sums over the runs (module docstring): per scan ``(K,)`` ``ospa``,
    ``gospa_loc``, ``gospa_missed``, ``gospa_false`` (p-th powers, m^p), ``n_est``, ``abs_card``;
    ``assigned_pos`` / ``assigned_count`` ``(K, N)``; ``switches (N,)`` label switches and
    ``id_switches (N,)`` CLEAR MOT identity switches (both on :func:`track_mapping`).
    ``pos``: position columns; ``sc``: :func:`per_scan_sets` and ``mapping``: :func:`track_mapping`
    when already computed."""
    n = est.x.shape[-1]
    B, K, M = est.exists.shape
    N = truth.x.shape[2]
    e, e_mask = est.x[..., pos], est.exists
    t, t_mask = truth.x[..., pos], truth.alive.expand(B, K, N)
    sc = set_scores(e, e_mask, t, t_mask, c, p) if sc is None else sc
    g = sc.gospa
    out = {"ospa": sc.ospa.sum(0).numpy(), "gospa_loc": g.localisation.sum(0).numpy(), "gospa_missed": g.missed.sum(0).numpy(),
           "gospa_false": g.false.sum(0).numpy(),
           "n_est": e_mask.sum(-1).sum(0).to(torch.float64).numpy(),
           "abs_card": (e_mask.sum(-1) - t_mask.sum(-1)).abs().sum(0).to(torch.float64).numpy()}
    label = labelled_assignment(e, e_mask, t, t_mask, c)  # (B, M): target of each track label
    hit = label.unsqueeze(-1) == torch.arange(N)  # (B, M, N)
    has = hit.any(1)  # (B, N): a label is assigned to the target
    which = hit.to(torch.int64).argmax(1)  # (B, N): that label
    idx = which[:, None, :, None].expand(B, K, N, n)
    x_lab = est.x.gather(2, idx)
    ex_lab = est.exists.gather(2, which[:, None, :].expand(B, K, N))
    both = has[:, None, :] & ex_lab & t_mask
    se = squared_error(x_lab, truth.x, pos)
    out["assigned_pos"] = _masked_sum(se, both)
    out["assigned_count"] = both.sum(0).to(torch.float64).numpy()
    mapping = track_mapping(est, truth, pos, c, p) if mapping is None else mapping
    out["switches"] = label_switches(mapping, t_mask).sum(0).to(torch.float64).numpy()
    out["id_switches"] = identity_switches(mapping, t_mask).sum(0).to(torch.float64).numpy()
    return out
