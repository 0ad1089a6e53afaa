"""The methods a scenario can run, behind one call: measurements in, state estimates out.

Every classical method starts from the same initiation prior per run and uses the matched
models (the recipe's CA motion and q, the scenario's fixed measurement deviations) unless its
options say otherwise (``q`` of the EKF / UKF, the IMM's two CA modes); a learned method reads
only the measurements. :func:`run_method` dispatches on ``MethodSpec.kind``; options set to
``tuned`` must have been replaced by numbers (:mod:`.tuning`) before it is called.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import torch

from ..filters import Gaussian, ekf, particle_filter, si_kf, ukf
from ..measurements import MeasurementModel
from ..motion import ConstantAcceleration
from ..nets.inference import Tracker
from ..rng import seeded_generator
from .scenario import MethodSpec


@dataclass
class Models:
    """What the classical methods share: motion and measurement models, interval ``dt`` (s),
    jerk PSD ``q`` (m^2/s^5), measurement covariance ``R (m, m)`` and deviations ``noise_std (3,)``."""

    motion: ConstantAcceleration
    model: MeasurementModel
    dt: float
    q: float
    R: torch.Tensor
    noise_std: torch.Tensor


@dataclass
class MethodOutput:
    """Estimates ``x (B, K, n)`` (float64, SI) and, where the method has one, covariances ``P (B, K, n, n)``."""

    x: torch.Tensor
    P: torch.Tensor | None = None


def method_stream(name: str) -> int:
    """A stable integer naming a method's random stream (independent of its place in the list)."""
    return zlib.crc32(name.encode())


def is_causal(spec: MethodSpec, trackers: dict[str, Tracker]) -> bool:
    """Whether an estimate at step k reads only scans up to k (compared with the filtering bound)."""
    return not trackers[spec.name].looks_ahead if spec.kind == "learned" else True


def _number(spec: MethodSpec, key: str) -> float:
    value = spec.option(key)
    if isinstance(value, str):  # 'tuned' left in place: a bug of the caller, not of the scenario
        raise AssertionError(f"method {spec.name!r}: option {key} is still {value!r}; resolve it with harness.tuning")
    return float(value)


def _q(spec: MethodSpec, key: str, m: Models, per_run: dict | None):
    """Jerk PSD (m^2/s^5) option ``key`` of ``spec`` (null: the recipe's q), or its per-run
    values ``(B,)`` where ``per_run`` gives them."""
    if per_run and key in per_run:
        return per_run[key]
    return m.q if spec.option(key) is None else _number(spec, key)


PER_RUN_OPTIONS = ("q", "q_quiet", "q_manoeuvre")
"""Options of the EKF, UKF and IMM that may be given per run (a grid search runs many values in one call)."""


def run_method(spec: MethodSpec, z: torch.Tensor, prior: Gaussian, m: Models, trackers: dict[str, Tracker],
               seed: tuple[int, ...], per_run: dict[str, torch.Tensor] | None = None) -> MethodOutput:
    """Run ``spec`` on measurements ``z (B, K, dim_z)``; ``seed`` names the block's random stream
    (used only by methods that draw, e.g. the particle filter); ``per_run`` optionally gives
    options of :data:`PER_RUN_OPTIONS` per run ``(B,)`` in place of ``spec``'s."""
    if spec.kind == "ekf":
        r = ekf(prior, z, m.motion, m.dt, _q(spec, "q", m, per_run), m.model, m.R)
        return MethodOutput(r.x, r.P)
    if spec.kind == "ukf":
        r = ukf(prior, z, m.motion, m.dt, _q(spec, "q", m, per_run), m.model, m.R)
        return MethodOutput(r.x, r.P)
    if spec.kind == "imm":
        from ..filters.imm import IMMMode, imm, markov_transition

        modes = [IMMMode(m.motion, _q(spec, "q_quiet", m, per_run)), IMMMode(m.motion, _q(spec, "q_manoeuvre", m, per_run))]
        r = imm(prior, z, modes, markov_transition(2, _number(spec, "stay")), m.dt, m.model, m.R)
        return MethodOutput(r.x, r.P)
    if spec.kind == "si_kf":
        std = m.noise_std.expand(z.shape[0], -1)
        r = si_kf(z, m.model, m.motion, m.dt, m.q, noise_std=std, prior=prior, refine_steps=int(spec.option("refine_steps")))
        return MethodOutput(r.x, r.P)
    if spec.kind == "particle_filter":
        g = seeded_generator(*seed, method_stream(spec.name))
        r = particle_filter(prior, z, m.motion, m.dt, m.q, m.model, m.R, n_particles=int(spec.option("particles")),
                            generator=g, roughening=float(spec.option("roughening")), on_lost="flag")
        return MethodOutput(r.x, r.P)
    if spec.kind == "learned":
        stride = spec.option("stride")
        return MethodOutput(trackers[spec.name].track(z, stride=None if stride is None else int(stride)))
    raise AssertionError(f"unhandled method kind {spec.kind!r}")  # MethodSpec validates kinds
