"""The figures a method kind reports beside the harness's own: one :class:`Metric` per family of
diagnostics, declared by the kind (``MethodKind.metrics``), in torchmetrics' spirit.

A metric is stateless; its state is the sums it keeps. Per block of runs the runner calls
:meth:`Metric.update` on the kind's :class:`~pmsr_nn.trackers.base.Estimates` and the block's
truth and keeps the sums it returns (``name -> array``) beside the harness's own (point, set,
track and trajectory sums, :mod:`pmsr_nn.harness.run.scoring`): they merge by adding over blocks,
except those named in ``per_run`` (one row per run, concatenated over blocks), so that shards and
banks merge bit for bit. :meth:`Metric.compute` turns the sums of every block into the row's fields
and per-scan curves. A metric reads the estimates' ``extras`` by its own keys (one metric per key);
the harness reads none of them. A kind declares no metric by default (a plug-in kind's row has the
harness's figures only).

The sum names are those recorded in every committed bank and ``results.json``: renaming one
orphans them.

* :class:`TrackLoss`: the S-MSJPDA paper's loss rule (JPDA kinds, Stone Soup's JPDA);
* :class:`DualityGap`: the relaxation's largest duality gap (P-MSJPDA);
* :class:`Labelling`: labels confirmed, GTDA's repairs and game rounds (the PHD kinds' labelling);
* :class:`PHDFigures`: the PHD's integral, particles and seconds (the PHD kinds);
* :class:`Unlabelled`: estimates without identities (a PHD's own, ``labelling: none``);
* :class:`TBDFrames`: the Remote Sensing 2020 figures per frame (track-before-detect kinds).

Shapes: ``B`` runs of a block, ``K`` scans (frames), ``N`` targets, ``S`` maps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
import torch

from ..metrics import track_loss
from ..simulation.products import Truth
from ..trackers.base import Estimates

PER_RUN_SUMS: set[str] = set()
"""Sums of every :class:`Metric` subclass kept per run (its ``per_run``): what block sums
concatenate rather than stack."""


@dataclass(frozen=True)
class BlockContext:
    """What a metric's update reads beside one block's estimates and truth: the position and
    velocity columns ``pos`` / ``vel`` it is scored on, the scenario's ``loss`` rule (its
    ``successive_scans`` and ``gate_range_sd_m``, m; None without one), and for unpaired tracks the
    set metrics' per-scan ``assignment (B, K, M)`` of tracks to targets (-1: none) and cut-off
    ``c_m`` (None for paired estimates)."""

    pos: list[int]
    vel: list[int]
    loss: Any = None
    assignment: Any = None
    c_m: float | None = None


@dataclass(frozen=True)
class RowContext:
    """What a metric's compute reads beside its sums: ``runs`` (``B``, every block), ``blocks``
    (their number), ``targets`` (``N``), the ``case`` and method ``spec`` of the row, and
    ``per_block``: the method's sums before the blocks are added (blocks first; per-run sums by run)."""

    runs: int
    blocks: int
    targets: int
    case: Any
    spec: Any
    per_block: dict


AFTER = ("point", "sets", "bounds")
"""Where a metric's fields go in a row: after the point figures (RMSE, ANEES, run time), after the
set and trajectory figures, or last, after the figures against the case's bounds."""


class Metric:
    """A family of a kind's figures: ``keys`` the sums it keeps (``per_run`` those kept per run),
    :meth:`update` per block, :meth:`compute` from every block's sums; ``after``: the part of a
    row its fields follow (:data:`AFTER`: where recorded rows have them, results.json keeping
    its fields' order)."""

    keys: tuple[str, ...] = ()
    per_run: tuple[str, ...] = ()
    after: str = "sets"

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if cls.after not in AFTER:
            raise ValueError(f"metric {cls.__name__}: after must be one of {AFTER}, got {cls.after!r}")
        PER_RUN_SUMS.update(cls.per_run)

    def update(self, est: Estimates, truth: Truth, ctx: BlockContext) -> dict[str, np.ndarray]:
        """One block's sums over its runs (``{}`` where the estimates carry nothing of it)."""
        return {}

    def compute(self, s: dict[str, np.ndarray], ctx: RowContext) -> tuple[dict, dict]:
        """The row's fields and per-scan curves from ``s`` (the method's sums added over every
        block, per-run sums concatenated; a sum some block lacks is not there)."""
        return {}, {}

    def labelled(self, est: Estimates) -> bool:
        """Whether the estimates' slots keep an identity over scans (False: no trajectories to score)."""
        return True


class TrackLoss(Metric):
    """``lost (N,)``: runs in which the paper's rule declares target ``t``'s track lost
    (:func:`~pmsr_nn.metrics.track_loss`, on the extras ``dummy_most_probable`` and
    ``gate_range_sd_m`` ``(B, K, N)``, where the scenario has a ``loss`` rule); the row's
    ``loss_probability``."""

    keys = ("lost",)
    after = "point"

    def update(self, est, truth, ctx):
        if ctx.loss is None or "dummy_most_probable" not in est.extras:
            return {}
        lost = track_loss(est.extras["dummy_most_probable"], est.extras["gate_range_sd_m"], ctx.loss.successive_scans,
                          ctx.loss.gate_range_sd_m)
        return {"lost": (lost >= 0).sum(0).to(torch.float64).numpy()}

    def compute(self, s, ctx):
        return ({"loss_probability": float(s["lost"].sum() / (ctx.runs * ctx.targets))} if "lost" in s else {}), {}


class DualityGap(Metric):
    """``gap``: the block's largest duality gap (extras ``max_duality_gap``, nats); the row's
    ``max_duality_gap``, the largest over the blocks."""

    keys = ("gap",)
    after = "point"

    def update(self, est, truth, ctx):
        return {"gap": np.asarray(float(est.extras["max_duality_gap"]))} if "max_duality_gap" in est.extras else {}

    def compute(self, s, ctx):
        return ({"max_duality_gap": float(ctx.per_block["gap"].max())} if "gap" in s else {}), {}


class Labelling(Metric):
    """A labelling's ``labels`` (labels confirmed, summed over the runs; extras ``labels (B,)``),
    GTDA's ``repaired`` (conflicts resolved after the game; ``repaired (B,)``) and ``game_rounds
    (K,)`` (rounds per scan, one count per block); the row's ``labels_per_run``,
    ``conflicts_repaired_per_run`` and ``game_rounds_mean`` (over scans and blocks)."""

    keys = ("labels", "repaired", "game_rounds")

    def update(self, est, truth, ctx):
        ex, out = est.extras, {}
        for key in ("labels", "repaired"):
            if key in ex:
                out[key] = np.asarray(float(ex[key].to(torch.float64).sum()))
        if "game_rounds" in ex:
            out["game_rounds"] = ex["game_rounds"].to(torch.float64).numpy()
        return out

    def compute(self, s, ctx):
        row = {}
        if "labels" in s:
            row["labels_per_run"] = float(s["labels"] / ctx.runs)
        if "repaired" in s:
            row["conflicts_repaired_per_run"] = float(s["repaired"] / ctx.runs)
        if "game_rounds" in s:
            row["game_rounds_mean"] = float(np.mean(s["game_rounds"] / ctx.blocks))
        return row, {}


class PHDFigures(Metric):
    """A PHD filter's ``phd_expected (K,)`` (its integral after each update) and ``phd_particles
    (K,)`` summed over the runs (extras ``(B, K)``), and ``phd_seconds`` (its seconds on the block);
    the row's ``phd_particles_mean`` and ``phd_seconds_per_run``, the curve ``phd_expected``."""

    keys = ("phd_expected", "phd_particles", "phd_seconds")

    def update(self, est, truth, ctx):
        ex, out = est.extras, {}
        for key in ("phd_expected", "phd_particles"):
            if key in ex:
                out[key] = ex[key].to(torch.float64).sum(0).numpy()
        if "phd_seconds" in ex:
            out["phd_seconds"] = np.asarray(float(ex["phd_seconds"]))
        return out

    def compute(self, s, ctx):
        row, curves = {}, {}
        if "phd_expected" in s:
            curves["phd_expected"] = (s["phd_expected"] / ctx.runs).tolist()
        if "phd_particles" in s:
            row["phd_particles_mean"] = float(np.mean(s["phd_particles"] / ctx.runs))
        if "phd_seconds" in s:
            row["phd_seconds_per_run"] = float(s["phd_seconds"] / ctx.runs)
        return row, curves


class Unlabelled(Metric):
    """Estimates without identity (extras ``unlabelled``: one set per scan, e.g. a PHD's own):
    ``unlabelled`` (1 per block); no trajectories are scored, and the row's figures that follow a
    track's label over scans are None (OSPA, GOSPA, cardinality, matched errors and fragmentations,
    gaps in a target's coverage, stay)."""

    keys = ("unlabelled",)

    def labelled(self, est):
        return not est.extras.get("unlabelled")

    def update(self, est, truth, ctx):
        return {} if self.labelled(est) else {"unlabelled": np.asarray(1.0)}

    def compute(self, s, ctx):
        if "unlabelled" not in s:
            return {}, {}
        return {"labelled": False, "label_switches_per_run": None, "label_switches_per_target": None,
                "id_switches_per_run": None, "id_switches_per_target": None,
                "rmse_pos_assigned_per_target_m": [None] * ctx.targets, "confirmed_tracks_per_target": None,
                "false_tracks_per_run": None, "track_loss_probability": None}, {}


@dataclass(frozen=True)
class TBDFrames(Metric):
    """Per-frame sums of a track-before-detect filter (extras ``tbd_detected (B, K)`` some
    component above the threshold, ``tbd_best_x (B, K, n)`` / ``tbd_best_r (B, K)`` the most
    probable component's mean and existence, ``tbd_snr_db (B, K, S)``, ``tbd_particles (B, K)``):
    ``tbd_detected (K,)``; ``tbd_pos``, ``tbd_vel (K,)`` squared position / velocity error of the
    most probable component against the nearest living target over ``tbd_hits (K,)`` runs that
    detect while a target lives; ``tbd_existence (K,)``, ``tbd_snr_db (K, S)``, ``tbd_particles
    (K,)``; per run ``tbd_run_pos_err (B, K)`` (NaN where the run does not detect or no target
    lives); from the set metrics' assignment of the same tracks, ``tbd_held (K,)`` the living
    targets a track is assigned to within the cut-off, ``tbd_living (K,)`` the living targets and
    ``tbd_unassigned (K,)`` the tracks assigned to none. The row's ``tbd`` part: the Remote Sensing
    2020 seed's figures, with what ``describe(spec, rd_maps)`` says of the filter, and the targets
    held and unassigned tracks that the set-metric table counts too."""

    describe: Callable
    per_run = ("tbd_run_pos_err",)
    after = "bounds"
    keys = ("tbd_detected", "tbd_pos", "tbd_vel", "tbd_hits", "tbd_existence", "tbd_snr_db", "tbd_particles",
            "tbd_run_pos_err", "tbd_held", "tbd_living", "tbd_unassigned")

    def update(self, est, truth, ctx):
        ex = est.extras
        if "tbd_detected" not in ex:
            return {}
        pos, vel = ctx.pos, ctx.vel
        det, xb = ex["tbd_detected"], ex["tbd_best_x"]  # (B, K), (B, K, n)
        t = truth.x  # (B, K, N, n)
        e_p = ((xb[:, :, None][..., pos] - t[..., pos]) ** 2).sum(-1)  # (B, K, N)
        e_v = ((xb[:, :, None][..., vel] - t[..., vel]) ** 2).sum(-1)
        e_p = torch.where(truth.alive, e_p, torch.full_like(e_p, float("inf")))
        e_p, nearest = e_p.min(-1)  # (B, K): the nearest living target
        e_v = e_v.gather(-1, nearest[..., None])[..., 0]
        hit = det & truth.alive.any(1)
        zero = torch.zeros((), dtype=e_p.dtype)
        held = {}
        if ctx.assignment is not None:
            a = ctx.assignment  # (B, K, M)
            mine = t.gather(2, a.clamp(min=0)[..., None].expand(*a.shape, t.shape[-1]))  # (B, K, M, n)
            near = ((est.x[..., pos] - mine[..., pos]) ** 2).sum(-1) < ctx.c_m ** 2
            assigned = est.exists & (a >= 0) & near
            B, K, N = t.shape[:3]
            held = {"tbd_held": assigned.sum((0, 2)).double().numpy(),
                    "tbd_living": truth.alive.expand(B, K, N).sum((0, 2)).double().numpy(),
                    "tbd_unassigned": (est.exists & ~assigned).sum((0, 2)).double().numpy()}
        return {**held, "tbd_detected": det.sum(0).double().numpy(), "tbd_pos": torch.where(hit, e_p, zero).sum(0).numpy(),
                "tbd_vel": torch.where(hit, e_v, zero).sum(0).numpy(), "tbd_hits": hit.sum(0).double().numpy(),
                "tbd_existence": ex["tbd_best_r"].sum(0).numpy(), "tbd_snr_db": ex["tbd_snr_db"].sum(0).numpy(),
                "tbd_particles": ex["tbd_particles"].sum(0).double().numpy(),
                "tbd_run_pos_err": torch.where(hit, e_p.sqrt(), torch.full_like(e_p, float("nan"))).numpy()}

    def compute(self, s, ctx):
        """The ``tbd`` part of the row (read by the report's track-before-detect section), from
        these sums and the harness's ``ospa`` and ``n_est``, of a case with maps (``case.info["rd_maps"]``)."""
        if "tbd_detected" not in s:
            return {}, {}
        B, case = ctx.runs, ctx.case
        info = case.info["rd_maps"]
        present = np.asarray(info["present"], dtype=bool)
        hits = np.where(s["tbd_hits"] > 0, s["tbd_hits"], np.nan)
        det = s["tbd_detected"] / B
        rms_p, rms_v = np.sqrt(s["tbd_pos"] / hits), np.sqrt(s["tbd_vel"] / hits)
        err = s["tbd_run_pos_err"]  # (B, K), NaN where the run does not detect
        med = np.array([np.median(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in err.T])
        last = int(np.nonzero(present)[0][-1])
        ospa = s["ospa"] / B
        return {"tbd": {**self.describe(ctx.spec, case.sensing.rd_maps),
                        "detected_frame_rate": det.tolist(),
                        "detected_rate_present": float(det[present].mean()),
                        "false_alarm_rate_absent": float(det[~present].mean()) if (~present).any() else None,
                        "detected_rate_table_frame": float(det[info["table_frame"] - 1]),
                        "rms_pos_m": rms_p.tolist(), "rms_vel_mps": rms_v.tolist(),
                        "rms_pos_last_present_m": float(rms_p[last]), "rms_vel_last_present_mps": float(rms_v[last]),
                        "median_pos_err_m": med.tolist(), "median_pos_err_last_present_m": float(med[last]),
                        "existence": (s["tbd_existence"] / B).tolist(), "ospa_frame_m": ospa.tolist(),
                        "ospa_mean_m": float(ospa.mean()), "snr_db": (s["tbd_snr_db"] / B).tolist(),
                        "particles": (s["tbd_particles"] / B).tolist(),
                        "estimates_per_frame": (s["n_est"] / B).tolist(), **self._held(s, present, B)}}, {}

    @staticmethod
    def _held(s: dict, present: np.ndarray, B: int) -> dict:
        """The share of living targets' frames a track is assigned to within the cut-off, and the
        unassigned tracks per frame (every frame), where the block sums have them."""
        if "tbd_held" not in s:
            return {}
        return {"targets_held_rate": float(s["tbd_held"][present].sum() / s["tbd_living"][present].sum()),
                "unassigned_tracks_per_frame": float(s["tbd_unassigned"].sum() / (B * len(present)))}
