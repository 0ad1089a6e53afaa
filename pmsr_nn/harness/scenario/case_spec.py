"""A designed scenario's cases (schema): fixed true flights, given by their start and segments,
or the targets of the scenario's own world.

Takes plain YAML data (through :func:`~pmsr_nn.config.from_dict`); gives frozen, checked specs:
a :class:`CaseSpec` is one inline flight (the papers' cases) or several :class:`TargetSpec` with
their own births and deaths, each a start and :class:`SegmentSpec` stretches of constant
along-track / cross-track acceleration; in a scenario with a ``world`` section (:mod:`.world`) a
case's targets are a formation, listed CV states or designed aircraft instead, and the case may
override the detections section (Pd, clutter, signals) and the initiation prior. Times in s,
distances in m, speeds in m/s, angles in degrees (bearing and heading clockwise from north).
:mod:`.trajectories` flies the designed flights.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ...config import require
from ...simulation.aircraft import AircraftSpec
from .world import FormationSpec, PriorSpec, TargetStateSpec

MAX_CASE_DURATION_S = 100_000.0
"""Longest trajectory of a case (about 28 h): every run holds every step of it in memory."""


@dataclass(frozen=True)
class SegmentSpec:
    """A stretch of flight with constant along-track and cross-track acceleration (m/s^2).

    ``across_mps2 > 0`` turns right (clockwise seen from above), ``along_mps2 > 0`` speeds up.
    """

    duration_s: float
    along_mps2: float = 0.0
    across_mps2: float = 0.0

    def __post_init__(self) -> None:
        require(self.duration_s > 0, f"segment duration_s must be positive, got {self.duration_s}")


FLIGHT_FIELDS = ("start_range_m", "start_bearing_deg", "speed_mps", "heading_deg")


@dataclass(frozen=True)
class TargetSpec:
    """One target's designed flight: start (range and bearing from the first transmitter, clockwise
    from north), initial speed and heading, then its segments; it is born ``birth_s`` after the
    case starts and flies until its segments end or until ``death_s`` (s from the case's start).
    Instead of range, bearing, speed and heading the start may be given as a position ``start_m``
    ``[x, y]`` (m) and velocity ``velocity_mps`` ``[vx, vy]`` at its birth (a straight flight is
    then sampled in closed form, ``start + t v``)."""

    name: str
    start_range_m: float | None = None
    start_bearing_deg: float | None = None
    speed_mps: float | None = None
    heading_deg: float | None = None
    segments: tuple[SegmentSpec, ...] = ()
    birth_s: float = 0.0
    death_s: float | None = None
    start_m: tuple[float, float] | None = None
    velocity_mps: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        require(bool(self.name), "a target needs a name")
        polar = [k for k in FLIGHT_FIELDS if getattr(self, k) is not None]
        cartesian = [k for k in ("start_m", "velocity_mps") if getattr(self, k) is not None]
        require(not (polar and cartesian), f"target {self.name!r}: give its start either as {', '.join(FLIGHT_FIELDS)} "
                                           "or as start_m and velocity_mps, not both")
        if cartesian:
            require(len(cartesian) == 2, f"target {self.name!r}: start_m and velocity_mps go together")
        else:
            missing = [k for k in FLIGHT_FIELDS if getattr(self, k) is None]
            require(not missing, f"target {self.name!r}: needs {', '.join(missing)} (or start_m and velocity_mps)")
        require(len(self.segments) > 0, f"target {self.name!r}: the trajectory is empty (no segments)")
        require(cartesian or self.speed_mps >= 0, f"target {self.name!r}: speed_mps must be >= 0")
        require(math.isfinite(self.birth_s) and self.birth_s >= 0, f"target {self.name!r}: birth_s must be >= 0")
        if self.death_s is not None:
            require(self.death_s > self.birth_s, f"target {self.name!r}: death_s {self.death_s:g} s is not after its "
                                                 f"birth_s {self.birth_s:g} s (death before birth)")
            require(self.death_s <= self.birth_s + self.duration_s,
                    f"target {self.name!r}: death_s {self.death_s:g} s is after its segments end "
                    f"({self.birth_s + self.duration_s:g} s)")

    @property
    def duration_s(self) -> float:
        """Length of the segments (s)."""
        return sum(s.duration_s for s in self.segments)

    @property
    def end_s(self) -> float:
        """When the target stops being seen (s from the case's start)."""
        return self.birth_s + self.duration_s if self.death_s is None else self.death_s


@dataclass(frozen=True)
class CaseSpec:
    """One case: a single designed flight given inline (start, speed, heading, segments: the
    papers' cases), or ``targets``, several :class:`TargetSpec` with their own births and deaths;
    ``title`` names it in the report. In a world scenario the targets are ``formation``, listed
    ``states`` or designed ``aircraft`` (one of them); ``detections`` overrides keys of the
    scenario's detections section (e.g. ``{pd: 0.6}``, ``{clutter: {per_scan: 100}}``,
    ``{front_end: null}``: detections from the statistical model), ``prior`` the world's
    initiation prior; ``reference_key`` is the case's key in the paper's tables."""

    name: str
    start_range_m: float | None = None
    start_bearing_deg: float | None = None
    speed_mps: float | None = None
    heading_deg: float | None = None
    segments: tuple[SegmentSpec, ...] = ()
    title: str = ""
    targets: tuple[TargetSpec, ...] = ()
    end_s: float | None = None
    methods: tuple[str, ...] = ()
    rd_maps: dict = field(default_factory=dict)
    formation: FormationSpec | None = None
    states: tuple[TargetStateSpec, ...] = ()
    aircraft: tuple[AircraftSpec, ...] = ()
    detections: dict = field(default_factory=dict)
    prior: PriorSpec | None = None
    reference_key: str | None = None

    def __post_init__(self) -> None:
        require(bool(self.name), "a case needs a name")
        dup = sorted({n for n in self.methods if self.methods.count(n) > 1})
        require(not dup, f"case {self.name!r}: methods lists {dup} more than once")
        inline = [k for k in FLIGHT_FIELDS if getattr(self, k) is not None]
        world = [k for k in ("formation", "states", "aircraft") if getattr(self, k)]
        if world:
            require(len(world) == 1 and not inline and not self.segments and not self.targets,
                    f"case {self.name!r}: give its targets one way (formation, states, aircraft, targets or one "
                    f"inline flight), got {', '.join(world + inline + (['targets'] if self.targets else []))}")
            names = [a.name for a in self.aircraft]
            dup = sorted({n for n in names if names.count(n) > 1})
            require(not dup, f"case {self.name!r}: duplicate aircraft name(s) {dup}")
            require(self.end_s is None, f"case {self.name!r}: end_s is for designed flights (a world case lasts "
                                        "world.scans)")
        elif self.targets:
            require(not inline and not self.segments, f"case {self.name!r}: give either targets or one inline flight "
                                                      f"({', '.join(FLIGHT_FIELDS)}, segments), not both")
            names = [t.name for t in self.targets]
            dup = sorted({n for n in names if names.count(n) > 1})
            require(not dup, f"case {self.name!r}: duplicate target name(s) {dup}")
        else:
            missing = [k for k in FLIGHT_FIELDS if getattr(self, k) is None]
            require(not missing, f"case {self.name!r}: needs {', '.join(missing)} (or a list of targets)")
            require(len(self.segments) > 0, f"case {self.name!r}: the trajectory is empty (no segments)")
            require(self.speed_mps >= 0, f"case {self.name!r}: speed_mps must be >= 0")
        if self.end_s is not None:
            last = max(t.end_s for t in self.flights())
            require(math.isfinite(self.end_s) and self.end_s >= last,
                    f"case {self.name!r}: end_s {self.end_s:g} s is before its last target ends ({last:g} s)")

    @property
    def in_world(self) -> bool:
        """Whether the case's targets live in the scenario's world (formation, states, aircraft)."""
        return bool(self.formation or self.states or self.aircraft)

    def flights(self) -> tuple[TargetSpec, ...]:
        """The case's targets (an inline flight is one target named like the case, born at 0)."""
        if self.targets:
            return self.targets
        return (TargetSpec(self.name, self.start_range_m, self.start_bearing_deg, self.speed_mps, self.heading_deg,
                           self.segments),)

    @property
    def duration_s(self) -> float:
        """How long the case lasts (s): ``end_s`` (the scans go on after the last target died), or
        until its last target ends."""
        return max(t.end_s for t in self.flights()) if self.end_s is None else self.end_s


FITEE2023_TRAJECTORIES = (
    CaseSpec("trajectory_1", 4000.0, 130.0, 10.0, 20.0, (SegmentSpec(1000.0),), "1: steady flight, 10 m/s"),
    CaseSpec("trajectory_2", 9000.0, 35.0, 5.0, 180.0, (SegmentSpec(1000.0, along_mps2=0.015),),
             "2: sustained acceleration, 5 to 20 m/s"),
    CaseSpec("trajectory_3", 7800.0, 140.0, 12.0, 0.0, (SegmentSpec(300.0), SegmentSpec(700.0, across_mps2=0.02)),
             "3: straight, then a 64-deg right turn"),
)
"""The three trajectories of ``evaluate/fitee2023_three_trajectories.yaml`` (a test keeps them
equal), built in so that ``pmsr demo`` needs no file."""
