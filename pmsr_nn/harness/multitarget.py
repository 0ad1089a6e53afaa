"""Multi-target studies (``kind: multitarget``, schema): a formation of targets (or listed
states, or designed aircraft) seen through missed detections and clutter, every multi-target
tracker on the same Monte Carlo draws.

Takes plain YAML data (through :func:`~pmsr_nn.config.from_dict`); gives a frozen, checked
:class:`MultiTargetScenario` (a bad field is refused in one line). :mod:`.prepare_multitarget`
turns it into the runner's :class:`~.prepared.Setup`; the runner runs it and :mod:`.report`
writes it like any scenario.

Cases vary the detection probability, the clutter count and the spacing of the formation
(:class:`MTCaseSpec`), which gives the S-MSJPDA paper's sweeps (Figs. 4-7, Tables 1-2) as one
scenario each. Distances in m, speeds in m/s, Doppler in Hz, ``dt_s`` in s.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import torch

from ..config import from_dict, require, to_dict
from ..frontend.chain import FrontEndSpec
from ..methods import method_kind
from ..simulation.aircraft import AircraftSpec
from ..simulation.detections import ClutterSpec
from ..simulation.recipe import GeometrySpec, ReceiverSpec, TransmitterSpec
from .scenario import SetMetricSpec, StudyFile


@dataclass(frozen=True)
class FormationSpec:
    """``count`` targets side by side, ``spacing_m`` apart across the common velocity
    ``velocity_mps`` (east, north), the formation's centre at ``centre_m`` at the first scan."""

    count: int = 4
    centre_m: tuple[float, float] = (-25_000.0, -20_000.0)
    velocity_mps: tuple[float, float] = (200.0, 244.1)
    spacing_m: float = 2000.0

    def __post_init__(self) -> None:
        require(self.count >= 1, f"targets.count must be at least 1, got {self.count}")
        require(self.spacing_m >= 0, f"targets.spacing_m must be >= 0, got {self.spacing_m}")

    def initial_states(self, spacing_m: float) -> torch.Tensor:
        """CV states ``(count, 4)`` ``[x, vx, y, vy]`` at the first scan."""
        v = torch.tensor(self.velocity_mps, dtype=torch.float64)
        speed = float(v.norm())
        across = torch.tensor([v[1], -v[0]], dtype=torch.float64) / max(speed, 1e-12)  # to the right of the track
        offsets = (torch.arange(self.count, dtype=torch.float64) - (self.count - 1) / 2) * spacing_m
        pos = torch.tensor(self.centre_m, dtype=torch.float64) + offsets[:, None] * across
        return torch.stack([pos[:, 0], v[0].expand(self.count), pos[:, 1], v[1].expand(self.count)], dim=-1)


@dataclass(frozen=True)
class TargetStateSpec:
    """One target's state at the first scan: ``position_m`` and ``velocity_mps`` ([x, y] or
    [x, y, z], the scenario's ``dimensions``)."""

    position_m: tuple[float, ...]
    velocity_mps: tuple[float, ...]

    def __post_init__(self) -> None:
        require(len(self.position_m) == len(self.velocity_mps) and len(self.position_m) in (2, 3)
                and all(math.isfinite(v) for v in (*self.position_m, *self.velocity_mps)),
                f"a target's position_m and velocity_mps must be finite [x, y] or [x, y, z], got "
                f"{list(self.position_m)} / {list(self.velocity_mps)}")

    def state(self) -> list[float]:
        """Axis-major CV state ``[x, vx, y, vy(, z, vz)]``."""
        return [v for p, u in zip(self.position_m, self.velocity_mps) for v in (p, u)]


@dataclass(frozen=True)
class MTNoiseSpec:
    """Deviations of the detections: bistatic range (m) and Doppler (Hz); with ``range_rate_mps``
    the detections measure bistatic range-rate (m/s) instead of Doppler (``doppler_hz`` unused),
    except those from signals (``front_end``), which measure Doppler with the deviation
    ``range_rate_mps`` converted through each pair's carrier."""

    range_m: float = 1000.0
    doppler_hz: float = 1.0
    range_rate_mps: float | None = None

    def __post_init__(self) -> None:
        require(self.range_m > 0 and self.doppler_hz > 0, "noise deviations must be positive")
        require(self.range_rate_mps is None or (self.range_rate_mps > 0 and math.isfinite(self.range_rate_mps)),
                f"noise range_rate_mps must be positive, got {self.range_rate_mps}")


@dataclass(frozen=True)
class MTMotionSpec:
    """CV motion of truth and trackers: interval ``dt_s``; ``model`` ``cv`` (discrete white
    acceleration, ``q`` its variance in m^2/s^4) or ``cv_continuous`` (continuous white
    acceleration, ``q`` its PSD in m^2/s^3); ``vertical_q``: the vertical axis's q in 3-D
    (default: ``q``). ``truth``: ``sampled`` (each run's flights drawn with that process noise) or
    ``straight`` (every run flies the same straight lines; the trackers still assume ``q``)."""

    dt_s: float = 1.0
    q: float = 1.0
    model: Literal["cv", "cv_continuous"] = "cv"
    vertical_q: float | None = None
    truth: Literal["sampled", "straight"] = "sampled"

    def __post_init__(self) -> None:
        require(self.dt_s > 0 and self.q >= 0, "motion: dt_s must be positive and q non-negative")
        require(self.vertical_q is None or self.vertical_q >= 0, "motion: vertical_q must be non-negative")

    def q_per_axis(self, dims: int):
        """``q`` as the trackers use it: a float, or a per-axis tensor when the vertical one differs."""
        if dims == 2 or self.vertical_q is None or self.vertical_q == self.q:
            return self.q
        return torch.tensor([self.q, self.q, self.vertical_q], dtype=torch.float64)


@dataclass(frozen=True)
class PriorSpec:
    """Track initiation: truth plus a draw from ``N(0, P0)``, ``P0`` from these deviations (in 3-D
    ``altitude_m`` and ``vertical_mps`` for the vertical axis; default the horizontal ones)."""

    position_m: float = 500.0
    velocity_mps: float = 20.0
    altitude_m: float | None = None
    vertical_mps: float | None = None

    def __post_init__(self) -> None:
        require(self.position_m > 0 and self.velocity_mps > 0, "prior deviations must be positive")
        require((self.altitude_m is None or self.altitude_m > 0) and (self.vertical_mps is None or self.vertical_mps > 0),
                "prior deviations must be positive")

    def sd(self, dims: int = 2) -> torch.Tensor:
        sd = [self.position_m, self.velocity_mps] * 2
        if dims == 3:
            sd += [self.altitude_m or self.position_m, self.vertical_mps or self.velocity_mps]
        return torch.tensor(sd, dtype=torch.float64)


@dataclass(frozen=True)
class LossSpec:
    """The paper's loss rule: dummy most probable ``successive_scans`` in a row, or the predicted
    bistatic-range deviation above ``gate_range_sd_m``."""

    successive_scans: int = 4
    gate_range_sd_m: float = 5000.0


@dataclass(frozen=True)
class MTMethodSpec:
    """A tracker of the study: ``kind`` a registered method kind that reads detections
    (:mod:`pmsr_nn.methods`); ``m_best`` overrides the scenario's ``tracker.m_best``; ``options``
    the kind's other options (e.g. a PMHT's ``window``)."""

    name: str
    kind: str
    m_best: int | None = None  # None: the scenario's tracker.m_best
    options: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        require(bool(self.name) and "/" not in self.name, f"method name {self.name!r} must be non-empty, without '/'")
        kind = method_kind(self.kind)
        require(kind.reads == "detections", f"method {self.name!r}: kind {self.kind} reads {kind.reads}; a multi-target "
                                            "study runs trackers of detections (put it in a designed scenario)")
        require(self.m_best is None or "m_best" in kind.options, f"method {self.name!r}: kind {self.kind} has no m_best")


@dataclass(frozen=True)
class TrackerSpec:
    m_best: int = 10
    gate_probability: float = 0.999
    relaxation_iterations: int = 20


@dataclass(frozen=True)
class MTCaseSpec:
    """One setting: ``pd``, ``clutter_per_scan``, ``spacing_m`` and ``prior`` override the
    scenario's; ``signals: false`` draws this case's detections from the statistical model even
    when the scenario has a ``front_end``; ``reference_key`` is the key of this case in the paper's
    tables (default: none)."""

    name: str
    title: str = ""
    pd: float | None = None
    clutter_per_scan: float | None = None
    spacing_m: float | None = None
    prior: PriorSpec | None = None
    signals: bool = True
    reference_key: str | None = None


@dataclass(frozen=True)
class MTReferenceSpec:
    """The paper's tables in ``file`` (dotted keys): ``timing`` run times (method -> reference_key
    -> seconds per run); ``velocity_rmse`` per-target velocity RMSE (paper method -> list) and
    ``anees`` per-target ANEES (a list, the paper's proposed method; the paper's NEES is not
    divided by the state dimension); ``methods`` maps our method names to the paper's keys."""

    timing: str | None = None
    file: str = "reference/paper_tables.json"
    label: str = "paper"
    velocity_rmse: str | None = None
    anees: str | None = None
    methods: dict = field(default_factory=dict)
    setup: str | None = None  # the paper's stated set-up (dotted key), shown beside the scenario's


DEFAULT_GEOMETRY = GeometrySpec(
    transmitters=(TransmitterSpec((-38_000.0, 12_000.0), 93.1e6), TransmitterSpec((26_000.0, 31_000.0), 90.9e6),
                  TransmitterSpec((14_000.0, -42_000.0), 99.9e6)),
    receivers=(ReceiverSpec(position_m=(0.0, 0.0)),))
"""Three FM transmitters tens of km around one receiver (the paper's map is a sketch; see
evaluate/access2019_msjpda.yaml)."""


@dataclass(frozen=True)
class MultiTargetScenario(StudyFile):
    name: str
    cases: tuple[MTCaseSpec, ...]
    methods: tuple[MTMethodSpec, ...]
    kind: Literal["multitarget"] = "multitarget"
    description: str = ""
    seed: int = 0
    mc_runs: int = 100
    block_runs: int = 10
    scans: int = 50
    geometry: GeometrySpec = DEFAULT_GEOMETRY
    targets: FormationSpec = FormationSpec()
    initial_states: tuple[TargetStateSpec, ...] = ()
    aircraft: tuple[AircraftSpec, ...] = ()
    min_altitude_m: float = 100.0
    max_range_m: float | None = None
    dimensions: int = 2
    noise: MTNoiseSpec = MTNoiseSpec()
    motion: MTMotionSpec = MTMotionSpec()
    prior: PriorSpec = PriorSpec()
    pd: float = 0.8
    clutter: ClutterSpec = ClutterSpec()
    illuminator_known: bool = True
    front_end: FrontEndSpec | None = None
    tracker: TrackerSpec = TrackerSpec()
    loss: LossSpec = LossSpec()
    converged_from_scan: int = 10
    sweep: Literal["none", "pd", "clutter_per_scan", "spacing_m"] = "none"
    reference: MTReferenceSpec | None = None
    set_metrics: SetMetricSpec = SetMetricSpec()
    base_dir: str = field(default=".", init=False, compare=False)

    def __post_init__(self) -> None:
        require(1 <= self.mc_runs <= 10_000_000 and self.block_runs >= 1,
                f"mc_runs must be in [1, 10,000,000] and block_runs at least 1, got {self.mc_runs:,} and {self.block_runs}")
        require(self.seed >= 0, f"seed must be non-negative, got {self.seed}")
        require(2 <= self.scans <= 100_000, f"scans must be in [2, 100000], got {self.scans}")
        require(0 <= self.converged_from_scan < self.scans, "converged_from_scan must be a scan index")
        require(len(self.cases) > 0 and len(self.methods) > 0, "a scenario needs cases and methods")
        for what, names in (("case", [c.name for c in self.cases]), ("method", [m.name for m in self.methods])):
            dup = sorted({n for n in names if names.count(n) > 1})
            require(not dup, f"duplicate {what} name(s): {dup}")
        for c in self.cases:
            require(c.pd is None or 0 < c.pd <= 1, f"case {c.name!r}: pd must be in (0, 1]")
            require(c.clutter_per_scan is None or 0 <= c.clutter_per_scan <= 100_000,
                    f"case {c.name!r}: clutter_per_scan must be in [0, 100000] (the papers use up to 500)")
            require(c.spacing_m is None or c.spacing_m >= 0, f"case {c.name!r}: spacing_m must be >= 0")
        require(self.dimensions in (2, 3), f"dimensions must be 2 or 3, got {self.dimensions}")
        for i, t in enumerate(self.initial_states):
            require(len(t.position_m) == self.dimensions, f"initial_states[{i}]: {len(t.position_m)}-D state in a "
                                                          f"{self.dimensions}-D scenario")
        require(self.dimensions == 2 or self.initial_states or self.aircraft,
                "a 3-D scenario lists its targets in initial_states or aircraft")
        require(not (self.aircraft and self.initial_states), "give the targets as aircraft or initial_states, not both")
        require(not self.aircraft or self.dimensions == 3, "aircraft fly in 3-D: set dimensions: 3")
        names = [a.name for a in self.aircraft]
        dup = sorted({n for n in names if names.count(n) > 1})
        require(not dup, f"duplicate aircraft name(s): {dup}")
        require(self.max_range_m is None or self.max_range_m > 0, f"max_range_m must be positive, got {self.max_range_m}")
        require(math.isfinite(self.min_altitude_m), f"min_altitude_m must be finite, got {self.min_altitude_m}")
        require(self.sweep != "spacing_m" or not (self.initial_states or self.aircraft),
                "a spacing_m sweep needs the formation, not initial_states or aircraft")
        if self.front_end is not None:
            require(self.illuminator_known, "detections from signals (front_end) are per transmitter: set "
                                            "illuminator_known true")
            require(all(k < self.scans for k in self.front_end.example_scans),
                    f"front_end example_scans {list(self.front_end.example_scans)} must be below scans ({self.scans})")

    def initial_states_for(self, spacing_m: float) -> torch.Tensor:
        """CV states ``(count, 2 * dimensions)`` at the first scan."""
        if self.initial_states:
            return torch.tensor([t.state() for t in self.initial_states], dtype=torch.float64)
        return self.targets.initial_states(spacing_m)

    def case_settings(self, case: MTCaseSpec) -> tuple[float, ClutterSpec, float]:
        """``(pd, clutter, spacing_m)`` of a case."""
        pd = self.pd if case.pd is None else case.pd
        clutter = self.clutter if case.clutter_per_scan is None else dataclasses.replace(self.clutter,
                                                                                         per_scan=case.clutter_per_scan)
        spacing = self.targets.spacing_m if case.spacing_m is None else case.spacing_m
        return pd, clutter, spacing

    def to_dict(self) -> dict:
        d = to_dict(self)
        if self.set_metrics == SetMetricSpec():
            del d["set_metrics"]
        if not self.aircraft:  # the fields of designed aircraft, only where there are some
            for key in ("aircraft", "min_altitude_m", "max_range_m"):
                del d[key]
        if self.noise.range_rate_mps is None:
            del d["noise"]["range_rate_mps"]
        if self.reference is not None and self.reference.setup is None:
            del d["reference"]["setup"]
        return d


def is_multitarget(data: dict) -> bool:
    return isinstance(data, dict) and data.get("kind") == "multitarget"


def multitarget_from_dict(data: dict, base_dir: str | Path = ".", where: str = "scenario") -> MultiTargetScenario:
    sc = from_dict(MultiTargetScenario, data, where=where)
    object.__setattr__(sc, "base_dir", str(Path(base_dir).resolve()))
    return sc
