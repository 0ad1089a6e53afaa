"""Planar flight kinematics from along-track / cross-track accelerations, and random drone
manoeuvres built on them.

One integrator serves the harness's designed trajectories (Python floats, one flight) and the
simulator's manoeuvring tracks (tensors ``(B,)``, a batch of flights): :func:`flight_substep`
and :func:`ca_sample` are written once against a small set of operations (:data:`SCALAR` or
:data:`BATCHED`), so both paths do the same arithmetic. Speed ``v`` (m/s) changes with the
along-track acceleration, heading ``psi`` (rad, clockwise from north) with the cross-track one
(``across / v``: a coordinated turn, ``across > 0`` turns right); position follows the velocity.

Manoeuvres (:func:`draw_schedule`, :func:`integrate_manoeuvres`): between quiet stretches a
track flies episodes of a coordinated turn or a speed change, each episode a segment whose
acceleration is reached through a linear ramp of ``ramp_s`` and left through another (the ramp
of the next, quiet segment), exactly as consecutive :class:`~pmsr_nn.harness.scenario.case_spec.SegmentSpec`
segments are. A speed change moves the speed by exactly ``acceleration x duration``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

MIN_TURN_SPEED = 1e-9
"""Below this speed (m/s) the heading is held (a turn rate ``across / v`` is undefined at rest)."""


class _ScalarOps:
    """Python floats: one flight."""

    sin, cos = staticmethod(math.sin), staticmethod(math.cos)

    @staticmethod
    def nonneg(v):
        return max(0.0, v)

    @staticmethod
    def turn(psi, across, v, h):
        return psi + across / v * h if v > MIN_TURN_SPEED else psi


class _BatchedOps:
    """float64 tensors ``(B,)``: a batch of flights."""

    sin, cos = staticmethod(torch.sin), staticmethod(torch.cos)

    @staticmethod
    def nonneg(v):
        return v.clamp_min(0.0)

    @staticmethod
    def turn(psi, across, v, h):
        return torch.where(v > MIN_TURN_SPEED, psi + across / v.clamp_min(MIN_TURN_SPEED) * h, psi)


SCALAR, BATCHED = _ScalarOps(), _BatchedOps()


def flight_substep(x, y, v, psi, along, across, h: float, ops=SCALAR):
    """One semi-implicit sub-step of ``h`` seconds: speed, then heading, then position (the mean
    of the old and new speed along the new heading). Returns ``(x, y, v, psi)``."""
    v_new = ops.nonneg(v + along * h)
    psi = ops.turn(psi, across, v, h)
    x = x + 0.5 * (v + v_new) * ops.sin(psi) * h
    y = y + 0.5 * (v + v_new) * ops.cos(psi) * h
    return x, y, v_new, psi


def ca_sample(x, y, v, psi, along, across, ops=SCALAR) -> list:
    """The CA state ``[x, vx, ax, y, vy, ay]`` (x east, y north) of a flight at speed ``v``,
    heading ``psi`` and commanded accelerations ``along`` / ``across`` (m/s^2)."""
    s_, c_ = ops.sin(psi), ops.cos(psi)
    ax, ay = along * s_ + across * c_, along * c_ - across * s_
    return [x, v * s_, ax, y, v * c_, ay]


@dataclass
class Schedule:
    """Manoeuvre episodes of ``B`` tracks, ``E`` per track in time order: ``start_s``, ``end_s``
    (s from the track's start), commanded ``along`` and ``across`` (m/s^2), all ``(B, E)``.
    Episodes may start after the track ends (they are then never flown)."""

    start_s: torch.Tensor
    end_s: torch.Tensor
    along: torch.Tensor
    across: torch.Tensor

    def begun(self, steps: int, dt: float) -> torch.Tensor:
        """Episodes begun by each sample time ``k dt`` (``start <= k dt``), ``(B, steps)`` (long)."""
        B = self.start_s.shape[0]
        first = torch.ceil(self.start_s / dt).clamp(max=steps).long()  # first sample at or after each start
        counts = torch.zeros(B, steps + 1, dtype=torch.long).scatter_add_(1, first, torch.ones_like(first))
        return counts.cumsum(1)[:, :steps]

    def commanded(self, t: torch.Tensor, begun: torch.Tensor, more: int, ramp_s: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Commanded ``(along, across)`` ``(B, S)`` (m/s^2) at times ``t (S,)`` (s) of one sampling
        interval: the last episode begun by ``t``, ramped up over ``ramp_s`` from its start and down
        over ``ramp_s`` from its end (episodes never overlap: quiet stretches last at least
        ``ramp_s``). ``begun (B,)``: episodes begun by the interval's start; ``more``: the most
        that begin within one interval."""
        B, E = self.start_s.shape
        tt = t.to(self.start_s.dtype).expand(B, -1)
        idx = (begun - 1).unsqueeze(1).expand(B, tt.shape[1])  # -1: before the first episode
        if more:
            nxt = begun.unsqueeze(1) + torch.arange(more)  # (B, more): the episodes that may begin next
            cand = self.start_s.gather(1, nxt.clamp(max=E - 1))
            started = (cand.unsqueeze(1) <= tt.unsqueeze(2)) & (nxt < E).unsqueeze(1)
            idx = idx + started.sum(-1)
        i = idx.clamp_min(0)
        s, e = self.start_s.gather(1, i), self.end_s.gather(1, i)
        w = ((tt - s) / ramp_s).clamp(0.0, 1.0) - ((tt - e) / ramp_s).clamp(0.0, 1.0)
        w = torch.where(idx >= 0, w, torch.zeros_like(w))
        return self.along.gather(1, i) * w, self.across.gather(1, i) * w


def _uniform(lo_hi, shape, g: torch.Generator) -> torch.Tensor:
    lo, hi = lo_hi
    return lo + (hi - lo) * torch.rand(shape, generator=g, dtype=torch.float64)


def episodes_needed(spec, duration_s: float) -> int:
    """Episodes per track that always cover ``duration_s``: the shortest cycle is the shortest
    quiet stretch plus the shortest episode."""
    shortest = spec.quiet_s[0] + min(spec.turn_s[0], spec.speed_change_s[0])
    return int(math.floor(duration_s / shortest)) + 1


def draw_schedule(spec, speed0: torch.Tensor, duration_s: float, g: torch.Generator) -> Schedule:
    """Episodes for tracks starting at speeds ``speed0 (B,)`` (m/s), covering ``duration_s``.

    ``spec`` is a :class:`~pmsr_nn.simulation.recipe.ManoeuvreSpec`. Every episode follows a quiet
    stretch drawn uniformly from ``quiet_s``; it is a coordinated turn with probability
    ``turn_probability`` (lateral acceleration uniform in ``turn_accel_mps2``, random side,
    duration in ``turn_s``, capped at ``max_turn_rate_deg_s`` times the speed), otherwise a speed
    change (uniform in ``speed_change_mps2``, random sign, duration in ``speed_change_s``) that is
    shortened so the commanded speed ends inside ``speed_mps`` (skipped if already at that edge).
    Seven ``(B, E)`` uniform draws, in a fixed order, whatever the outcome.
    """
    B, E = speed0.shape[0], episodes_needed(spec, duration_s)
    quiet = _uniform(spec.quiet_s, (B, E), g)
    is_turn = torch.rand((B, E), generator=g, dtype=torch.float64) < spec.turn_probability
    sign = torch.where(torch.rand((B, E), generator=g, dtype=torch.float64) < 0.5, -1.0, 1.0).to(torch.float64)
    turn_a, turn_d = _uniform(spec.turn_accel_mps2, (B, E), g), _uniform(spec.turn_s, (B, E), g)
    speed_a, speed_d = _uniform(spec.speed_change_mps2, (B, E), g), _uniform(spec.speed_change_s, (B, E), g)
    omega = math.radians(spec.max_turn_rate_deg_s)
    lo, hi = spec.speed_mps
    start, end = torch.empty_like(quiet), torch.empty_like(quiet)
    along, across = torch.zeros_like(quiet), torch.zeros_like(quiet)
    t, v = torch.zeros(B, dtype=torch.float64), speed0.to(torch.float64).clone()
    for e in range(E):  # sequential in the episode index only (the speed carries over); tracks are the batch
        turn = is_turn[:, e]
        a = sign[:, e] * speed_a[:, e]
        edge = torch.where(a > 0, torch.full_like(v, hi), torch.full_like(v, lo))
        d_speed = torch.minimum(speed_d[:, e], ((edge - v) / a).clamp_min(0.0))
        d = torch.where(turn, turn_d[:, e], d_speed)
        along[:, e] = torch.where(turn, 0.0, a)
        across[:, e] = torch.where(turn, sign[:, e] * torch.minimum(turn_a[:, e], omega * v), 0.0)
        start[:, e] = t + quiet[:, e]
        end[:, e] = start[:, e] + d
        v = v + along[:, e] * d
        t = end[:, e]
    return Schedule(start, end, along, across)


def integrate_manoeuvres(x0: torch.Tensor, schedule: Schedule, steps: int, dt: float, ramp_s: float,
                         substeps: int) -> torch.Tensor:
    """Fly tracks from CA states ``x0 (B, 6)`` (their position and velocity; the acceleration is
    ignored) through ``schedule``: states ``(B, steps, 6)`` every ``dt`` seconds, the acceleration
    the commanded one at the sample time. ``substeps`` sub-steps per interval (the only loop is
    over time)."""
    x, y = x0[:, 0].clone(), x0[:, 3].clone()
    v = torch.hypot(x0[:, 1], x0[:, 4])
    psi = torch.atan2(x0[:, 1], x0[:, 4])
    h = dt / substeps
    offsets = torch.arange(substeps, dtype=torch.float64) * h
    begun = schedule.begun(steps, dt)  # (B, steps)
    more = int((begun[:, 1:] - begun[:, :-1]).max()) if steps > 1 else 0
    out = torch.empty(x0.shape[0], steps, 6, dtype=torch.float64)
    for k in range(steps):
        if k:
            along, across = schedule.commanded((k - 1) * dt + offsets, begun[:, k - 1], more, ramp_s)
            for s in range(substeps):
                x, y, v, psi = flight_substep(x, y, v, psi, along[:, s], across[:, s], h, BATCHED)
        along, across = schedule.commanded(torch.tensor([k * dt]), begun[:, k], 0, ramp_s)
        out[:, k] = torch.stack(ca_sample(x, y, v, psi, along[:, 0], across[:, 0], BATCHED), -1)
    return out
