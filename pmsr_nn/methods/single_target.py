"""Single-target methods on every target's own measurement stream (association known).

Every classical method starts from the same initiation prior per run and target and uses the
matched models (the motion model and its q, the scenario's measurement deviations) unless its
options say otherwise (``q`` of the EKF / UKF, the IMM's two CA modes); a learned method reads
only the measurements. :func:`run_single` runs one kind on streams ``z (B, K, m)``;
:func:`per_target` runs it on each target over its life, targets with the same life stacked as
runs of one call. Options set to ``tuned`` must have been replaced by numbers
(:mod:`pmsr_nn.harness.scenario.tuning`) before a call.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..filters import Gaussian, ekf, particle_filter, si_kf, ukf
from ..filters.imm import IMMMode, imm, markov_transition
from ..rng import seeded_generator
from ..trackers.base import Estimates
from . import MethodCall, MethodKind, Models, Option, method_stream, register


@dataclass
class MethodOutput:
    """Estimates ``x (B, K, n)`` (float64, SI) and, where the method has one, covariances ``P (B, K, n, n)``."""

    x: torch.Tensor
    P: torch.Tensor | None = None


def _number(spec, key: str) -> float:
    value = spec.option(key)
    if isinstance(value, str):  # 'tuned' left in place: a bug of the caller, not of the scenario
        raise RuntimeError(f"method {spec.name!r}: option {key} is still {value!r}; resolve it with "
                           "harness.scenario.tuning")
    return float(value)


def _q(spec, key: str, m: Models, per_run: dict | None):
    """Jerk PSD (m^2/s^5) option ``key`` of ``spec`` (null: the recipe's q), or its per-run
    values ``(B,)`` where ``per_run`` gives them."""
    if per_run and key in per_run:
        return per_run[key]
    return m.q if spec.option(key) is None else _number(spec, key)


PER_RUN_OPTIONS = ("q", "q_quiet", "q_manoeuvre")
"""Options of the EKF, UKF and IMM that may be given per run (a grid search runs many values in one call)."""


def run_single(spec, z: torch.Tensor, prior: Gaussian, m: Models, resource, seed: tuple[int, ...],
               per_run: dict[str, torch.Tensor] | None = None) -> MethodOutput:
    """Run single-target ``spec`` on measurements ``z (B, K, dim_z)``; ``seed`` names the block's
    random stream (used only by methods that draw, e.g. the particle filter); ``per_run``
    optionally gives options of :data:`PER_RUN_OPTIONS` per run ``(B,)`` in place of ``spec``'s;
    ``resource`` is a learned method's :class:`~pmsr_nn.nets.inference.Tracker`."""
    if spec.kind == "ekf":
        r = ekf(prior, z, m.motion, m.dt, _q(spec, "q", m, per_run), m.model, m.R)
        return MethodOutput(r.x, r.P)
    if spec.kind == "ukf":
        r = ukf(prior, z, m.motion, m.dt, _q(spec, "q", m, per_run), m.model, m.R)
        return MethodOutput(r.x, r.P)
    if spec.kind == "imm":
        modes = [IMMMode(m.motion, _q(spec, "q_quiet", m, per_run)), IMMMode(m.motion, _q(spec, "q_manoeuvre", m, per_run))]
        r = imm(prior, z, modes, markov_transition(2, _number(spec, "stay"), z.device), m.dt, m.model, m.R)
        return MethodOutput(r.x, r.P)
    if spec.kind == "si_kf":
        std = m.noise_std.expand(z.shape[0], -1)
        r = si_kf(z, m.model, m.motion, m.dt, m.q, noise_std=std, prior=prior, refine_steps=int(spec.option("refine_steps")))
        return MethodOutput(r.x, r.P)
    if spec.kind == "particle_filter":
        g = seeded_generator(*seed, method_stream(spec.name), device=z.device)  # the filter's draws: on its device
        r = particle_filter(prior, z, m.motion, m.dt, m.q, m.model, m.R, n_particles=int(spec.option("particles")),
                            generator=g, roughening=float(spec.option("roughening")), on_lost="flag")
        return MethodOutput(r.x, r.P)
    if spec.kind == "learned":
        stride = spec.option("stride")
        return MethodOutput(resource.track(z, stride=None if stride is None else int(stride),
                                           whole=spec.option("inference") == "whole_sequence"))
    raise ValueError(f"{spec.kind!r} is not a single-target method kind")


def lives(alive: torch.Tensor) -> list[tuple[int, int, int]]:
    """Each target's life ``(target, first scan, end scan)`` from ``alive (K, N)``; a life must be
    one stretch of scans (checked when a scenario is prepared)."""
    out = []
    for t in range(alive.shape[1]):
        on = torch.nonzero(alive[:, t]).flatten()
        if not len(on):  # not alive in these scans (a slice of them): no estimates
            continue
        out.append((t, int(on[0]), int(on[-1]) + 1))
    return out


def per_target(call: MethodCall) -> Estimates:
    """Run ``call.spec`` on each target's stream over its life and gather labelled estimates
    (slot ``i`` = target ``i``). Each stream starts at its target's birth, so targets whose lives
    are equally long are one call, their runs stacked (a filter's cost is per scan, not per run)."""
    z, prior = call.product.z, call.product.prior  # (B, N, K, m), x (B, N, n)
    B, N, K, _ = z.shape
    n = prior.x.shape[-1]
    groups: dict[int, list[tuple[int, int]]] = {}
    for t, k0, k1 in lives(call.alive):
        groups.setdefault(k1 - k0, []).append((t, k0))
    x = z.new_full((B, K, N, n), float("nan"))
    P = None
    for i, (L, members) in enumerate(groups.items()):
        G = len(members)
        targets = [t for t, _ in members]
        zt = torch.stack([z[:, t, k0:k0 + L] for t, k0 in members], 1).reshape(B * G, L, -1)
        pt = Gaussian(prior.x[:, targets].reshape(B * G, n), prior.P[:, targets].reshape(B * G, n, n))
        seed = call.seed if len(groups) == 1 else (*call.seed, i)
        out = run_single(call.spec, zt, pt, call.models, call.resource, seed)
        xs = out.x.reshape(B, G, L, n)
        Ps = None if out.P is None else out.P.reshape(B, G, L, n, n)
        if Ps is not None and P is None:
            P = z.new_full((B, K, N, n, n), float("nan"))
        for j, (t, k0) in enumerate(members):
            x[:, k0:k0 + L, t] = xs[:, j]
            if Ps is not None:
                P[:, k0:k0 + L, t] = Ps[:, j]
    return Estimates(x, call.alive.expand(B, K, N), P)


def _load_learned(spec, context):
    """The checkpoint of a learned method, loaded and checked against the scenario."""
    from ..nets.inference import Tracker

    t = Tracker.load(context.path(spec.checkpoint), device=context.device)
    t.check_compatible(context.geometry, context.labels, context.dt, where=context.where, row=spec.name)
    stride = spec.option("stride")
    if spec.option("inference") == "whole_sequence" and t.net.context[0] is not None:
        raise ConfigError(f"method {spec.name!r}: inference whole_sequence is for recurrent networks; "
                          f"{spec.checkpoint} is a {t.model.kind}, which reads {t.net.context[0] + 1} scans (drop the option)")
    if stride is not None and stride > t.window:
        raise ConfigError(f"method {spec.name!r}: stride {stride} is longer than the network's window of "
                          f"{t.window} samples (scans between windows would get no estimate)")
    return t


def _check_learned(spec, alive: torch.Tensor, tracker, case: str) -> None:
    short = [(t, k1 - k0) for t, k0, k1 in lives(alive) if k1 - k0 < tracker.window]
    if short:
        what = f"case {case!r} has {short[0][1]} steps" if alive.shape[1] == 1 else \
            f"case {case!r}: target(s) {[t for t, _ in short]} live {[L for _, L in short]} steps"
        raise ConfigError(f"{what}, fewer than {spec.name}'s window of {tracker.window}")


Q = Option(None, float, 0.0, 1.0e6, nullable=True, tunable=True, null="the recipe's q")  # jerk PSD (m^2/s^5); null: the recipe's q
for _kind, _options, _extra in (
    ("ekf", {"q": Q}, {"description": "extended Kalman filter, CA motion (the FITEE 2023 baseline)"}),
    ("ukf", {"q": Q}, {"description": "unscented Kalman filter, CA motion"}),
    # two CA modes (EKF moments): quiet (null = the recipe's q) and manoeuvring, and the probability of
    # staying in a mode per step (diagonal of the 2x2 Markov matrix)
    ("imm", {"q_quiet": Q, "q_manoeuvre": Option(1.0, float, 0.0, 1.0e6, tunable=True),
             "stay": Option(0.95, float, 0.0, 1.0, tunable=True)},
     {"description": "interacting multiple model: two CA modes, quiet and manoeuvring"}),
    # refine_steps 0 is the paper's plain spherical interpolation
    ("si_kf", {"refine_steps": Option(0, int, 0, 100)},
     {"description": "spherical-interpolation position fixes fed to a linear Kalman filter (SI+KF)"}),
    # a block of runs x particles x 9 states must fit in memory
    ("particle_filter", {"particles": Option(2000, int, 1, 1_000_000), "roughening": Option(0.2, float, 0.0, 10.0)},
     {"description": "bootstrap particle filter with roughening"}),
    ("learned", {"stride": Option(None, int, 1, 1_000_000, nullable=True, null="the checkpoint's default stride"),
                 "inference": Option("windows", str, choices=("windows", "whole_sequence"))},
     {"needs_checkpoint": True, "load": _load_learned, "causal": lambda t: not t.looks_ahead, "check": _check_learned,
      "description": "a trained DFNN, MDFNN, RNN or KalmanNet (pmsr train) from its checkpoint"}),
):
    # the particle filter draws from the block's stream; the others are per run
    register(MethodKind(_kind, "measurements", per_target, _options, any_device=True,
                        batchable=_kind != "particle_filter", **_extra))
