"""Evaluation scenarios: what is simulated, how often, and which methods run on it (YAML).

A scenario names a dataset recipe (or takes the built-in one) (sensor geometry, motion model and its q, sampling interval,
Table 1 envelope), overrides its measurement noise with fixed deviations, and lists

* ``cases``: fixed true trajectories (:class:`CaseSpec`, drawn by :mod:`.trajectories`), each
  seen by every method through the same ``mc_runs`` measurement-noise draws;
* ``methods``: classical filters and learned trackers with their settings (:class:`MethodSpec`);
  an option of a classical filter set to ``tuned`` is chosen by a grid search on training tracks
  (``tuning``, :class:`TuningSpec`, run by :mod:`.tuning`) before anything is written.

Paths (recipe, checkpoints, reference file) are relative to the scenario file.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from ..config import from_dict, load_yaml, require
from ..errors import ConfigError
from ..methods import method_kind
from ..simulation.detections import ClutterSpec
from ..simulation.recipe import check_outliers
from ..tbd.scene import RDMapsSpec

TUNABLE = ("q", "q_quiet", "q_manoeuvre", "stay")
"""Options that may be ``tuned`` (chosen from ``tuning.<option>_grid``), in grid order; each is
marked ``tunable`` in its method kind (:mod:`pmsr_nn.methods`)."""

TUNABLE_RANGES: dict[str, tuple[float, float]] = {"q": (0.0, 1.0e6), "q_quiet": (0.0, 1.0e6),
                                                  "q_manoeuvre": (0.0, 1.0e6), "stay": (0.0, 1.0)}
"""Inclusive range of every grid of :class:`TuningSpec`."""

MAX_TUNING_TRACKS = 500
"""Most tuning tracks (one filter call holds all of them: 500 IMM runs of 1000 steps take ~0.2 GB)."""

MAX_TUNING_POINTS = 1000
"""Most grid points one method's search may have (the product of its tuned options' grids)."""


def _check_option(method: str, key: str, value, opt) -> None:
    if value is None and opt.nullable:
        return
    if value == "tuned" and opt.tunable:
        return
    if opt.choices:
        if value not in opt.choices:
            raise ConfigError(f"method {method!r}: option {key} must be one of {', '.join(opt.choices)}, "
                              f"got {value!r:.40}")
        return
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not number or (opt.kind is int and not isinstance(value, int)) or not (opt.lo <= value <= opt.hi):
        extra = " or 'tuned'" if opt.tunable else ""
        raise ConfigError(f"method {method!r}: option {key} must be {'an integer' if opt.kind is int else 'a number'} "
                          f"in [{opt.lo}, {opt.hi}]{extra}, got {value!r:.40}")


MAX_MC_RUNS = 10_000_000
"""Most Monte Carlo runs of a scenario (the papers use 100; per-run results are kept in memory)."""

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
    ``title`` names it in the report."""

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

    def __post_init__(self) -> None:
        require(bool(self.name), "a case needs a name")
        dup = sorted({n for n in self.methods if self.methods.count(n) > 1})
        require(not dup, f"case {self.name!r}: methods lists {dup} more than once")
        inline = [k for k in FLIGHT_FIELDS if getattr(self, k) is not None]
        if self.targets:
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


@dataclass(frozen=True)
class DetectionSpec:
    """Detections for multi-target trackers: every transmitter-receiver pair detects each living
    target with probability ``pd`` per scan and reports clutter (:class:`ClutterSpec`, its box over
    ``components``); the noise is the scenario's fixed noise."""

    pd: float = 0.9
    clutter: ClutterSpec = ClutterSpec()
    components: tuple[str, ...] = ("range", "range_rate", "azimuth")

    def __post_init__(self) -> None:
        require(0 < self.pd <= 1, f"detections.pd must be in (0, 1], got {self.pd}")
        allowed = ("range", "range_rate", "azimuth")
        require(len(self.components) > 0 and self.components[0] == "range"
                and all(c in allowed for c in self.components) and len(set(self.components)) == len(self.components),
                f"detections.components must start with range and be distinct names from {allowed}, "
                f"got {list(self.components)}")


@dataclass(frozen=True)
class SetMetricSpec:
    """Cut-off ``c_m`` (m) and order ``p`` of OSPA / GOSPA (and the cut-off of the label
    assignment behind per-target RMSE and label switches)."""

    c_m: float = 1000.0
    p: float = 2.0

    def __post_init__(self) -> None:
        require(math.isfinite(self.c_m) and self.c_m > 0, f"set_metrics.c_m must be a positive distance, got {self.c_m}")
        require(math.isfinite(self.p) and self.p >= 1, f"set_metrics.p must be >= 1, got {self.p}")


@dataclass(frozen=True)
class FixedNoiseSpec:
    """Measurement deviations used for every run (the paper's Section 4: 30 m, 2 m/s, 3 deg); with
    probability ``range_outlier_prob`` (per range measurement, pair and scan) a range error's
    deviation is ``range_outlier_scale`` times ``range_m``. The filters' ``R`` is the nominal one."""

    range_m: float = 30.0
    range_rate_mps: float = 2.0
    azimuth_deg: float = 3.0
    range_outlier_prob: float = 0.0
    range_outlier_scale: float = 10.0

    def __post_init__(self) -> None:
        require(min(self.range_m, self.range_rate_mps, self.azimuth_deg) > 0, "noise deviations must be positive")
        check_outliers("noise", self.range_outlier_prob, self.range_outlier_scale)

    @property
    def has_outliers(self) -> bool:
        return self.range_outlier_prob > 0

    def si(self) -> tuple[float, float, float]:
        return self.range_m, self.range_rate_mps, math.radians(self.azimuth_deg)


@dataclass(frozen=True)
class MethodSpec:
    """A method to run: ``kind`` names a registered method kind (:mod:`pmsr_nn.methods`: its product,
    options and defaults), ``options`` its settings, ``checkpoint`` the trained tracker of a kind
    that needs one (``learned``)."""

    name: str
    kind: str
    checkpoint: str | None = None
    options: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        require(bool(self.name) and "/" not in self.name, f"method name {self.name!r} must be non-empty, without '/'")
        kind = method_kind(self.kind)
        if kind.needs_checkpoint:
            require(self.checkpoint is not None, f"method {self.name!r}: a {self.kind} method needs a checkpoint")
        else:
            require(self.checkpoint is None, f"method {self.name!r}: kind {self.kind} takes no checkpoint")
        unknown = sorted(set(self.options) - set(kind.options))
        require(not unknown, f"method {self.name!r}: unknown option(s) {unknown} for kind {self.kind!r} "
                             f"(valid: {sorted(kind.options) or 'none'})")
        for key, value in self.options.items():
            _check_option(self.name, key, value, kind.options[key])

    def option(self, key: str):
        return self.options.get(key, method_kind(self.kind).options[key].default)

    def tuned(self) -> list[str]:
        """Options set to ``tuned``, in :data:`TUNABLE` order."""
        return [k for k in TUNABLE if self.options.get(k) == "tuned"]


@dataclass(frozen=True)
class TuningSpec:
    """The grid search behind options set to ``tuned``: ``tracks`` truth tracks drawn from
    ``recipe`` (the training recipe, relative to the scenario file; null = the scenario's) with
    generator stream ``seed``, measured with the scenario's fixed noise (outliers included); each
    method runs once per point of the product of its tuned options' grids (``<option>_grid``),
    and the point with the lowest position RMSE after the warm-up is used."""

    tracks: int = 50
    seed: int = 12345
    recipe: str | None = None
    q_grid: tuple[float, ...] = ()
    q_quiet_grid: tuple[float, ...] = ()
    q_manoeuvre_grid: tuple[float, ...] = ()
    stay_grid: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        require(1 <= self.tracks <= MAX_TUNING_TRACKS, f"tuning.tracks must be in [1, {MAX_TUNING_TRACKS}], "
                                                       f"got {self.tracks}")
        require(self.seed >= 0, f"tuning.seed must be non-negative, got {self.seed}")
        for key in TUNABLE:
            grid = self.grid(key)
            lo, hi = TUNABLE_RANGES[key]
            for v in grid:
                require(lo <= v <= hi, f"tuning.{key}_grid: values must be in [{lo}, {hi}], got {v}")
            dup = sorted({v for v in grid if grid.count(v) > 1})
            require(not dup, f"tuning.{key}_grid holds {dup} more than once")

    def grid(self, key: str) -> tuple[float, ...]:
        return getattr(self, f"{key}_grid")


@dataclass(frozen=True)
class ReferenceSpec:
    """Where the paper's numbers for this scenario are: ``table`` is a dotted key into ``file``
    whose value maps case name -> method -> number (or method -> number for one case);
    ``timing`` optionally one mapping method -> milliseconds for the run-time table."""

    table: str | None = None
    file: str = "reference/paper_tables.json"
    timing: str | None = None
    label: str = "paper"
    subarea_table: str | None = None

    def __post_init__(self) -> None:
        require(self.table is not None or self.subarea_table is not None,
                "reference needs a table (or a subarea_table: a track-before-detect sub-area study's)")


class StudyFile:
    """What every scenario kind shares (fields ``mc_runs``, ``block_runs``, ``base_dir``): Monte
    Carlo runs in blocks of ``block_runs``, paths relative to the YAML file's folder."""

    def path(self, relative: str) -> Path:
        """``relative`` resolved against the scenario file's folder (absolute paths unchanged)."""
        p = Path(relative).expanduser()
        return p if p.is_absolute() else Path(self.base_dir) / p

    @property
    def n_blocks(self) -> int:
        return math.ceil(self.mc_runs / self.block_runs)

    def block_runs_range(self, block: int) -> range:
        return range(block * self.block_runs, min(self.mc_runs, (block + 1) * self.block_runs))

    def keyed_reference(self) -> dict | None:
        """The entry ``reference.key`` (dotted) of the JSON ``reference.file`` with its ``label``, or a
        one-line :class:`ConfigError` naming the key and file; ``None`` without a reference."""
        ref = self.reference
        if ref is None:
            return None
        path = self.path(ref.file)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            for part in ref.key.split("."):
                data = data[part]
        except (OSError, ValueError, KeyError, TypeError):
            raise ConfigError(f"reference {ref.key!r} not found in {path}") from None
        return {"file": str(path), "key": ref.key, "label": ref.label, "table": data}

    def with_mc_runs(self, mc_runs: int | None):
        """The same study with ``mc_runs`` runs (``None``: unchanged)."""
        if mc_runs is None:
            return self
        new = dataclasses.replace(self, mc_runs=mc_runs)
        object.__setattr__(new, "base_dir", self.base_dir)
        return new


@dataclass(frozen=True)
class Scenario(StudyFile):
    name: str
    cases: tuple[CaseSpec, ...]
    methods: tuple[MethodSpec, ...]
    recipe: str | None = None  # None: the built-in FITEE 2023 CA recipe (= datasets/fitee2023_ca.yaml)
    seed: int = 0
    mc_runs: int = 100
    block_runs: int = 10
    noise: FixedNoiseSpec = FixedNoiseSpec()
    warmup_steps: int = 100
    divergence_m: float = 1000.0
    ramp_s: float = 60.0
    reference: ReferenceSpec | None = None
    tuning: TuningSpec | None = None
    detections: DetectionSpec | None = None
    set_metrics: SetMetricSpec = SetMetricSpec()
    random_streams: Literal["per_block", "per_product"] = "per_block"
    description: str = ""
    rd_maps: RDMapsSpec | None = None
    base_dir: str = field(default=".", init=False, compare=False)

    def __post_init__(self) -> None:
        require(self.seed >= 0, f"seed must be non-negative, got {self.seed}")
        self._check_case_overrides()
        require(1 <= self.mc_runs <= MAX_MC_RUNS, f"mc_runs must be in [1, {MAX_MC_RUNS:,}], got {self.mc_runs:,}")
        require(self.block_runs >= 1, f"block_runs must be at least 1, got {self.block_runs}")
        require(self.warmup_steps >= 0, f"warmup_steps must be >= 0, got {self.warmup_steps}")
        require(self.divergence_m > 0, f"divergence_m must be positive, got {self.divergence_m}")
        require(self.ramp_s >= 0, f"ramp_s must be >= 0, got {self.ramp_s}")
        require(len(self.cases) > 0, "a scenario needs at least one case")
        require(len(self.methods) > 0, "a scenario needs at least one method")
        for c in self.cases:
            require(c.duration_s <= MAX_CASE_DURATION_S,
                    f"case {c.name!r}: duration {c.duration_s:.3g} s is longer than the {MAX_CASE_DURATION_S:.0f} s "
                    "a case may last (the papers' trajectories last 1000 s)")
        for what, names in (("case", [c.name for c in self.cases]), ("method", [m.name for m in self.methods])):
            dup = sorted({n for n in names if names.count(n) > 1})
            require(not dup, f"duplicate {what} name(s): {dup}")
        for m in self.methods:
            reads = method_kind(m.kind).reads
            require(reads != "detections" or self.detections is not None,
                    f"method {m.name!r} (kind {m.kind}) reads detections, which this scenario does not make: add a "
                    "detections section (pd, clutter)")
        products = sorted({method_kind(m.kind).reads for m in self.methods if not method_kind(m.kind).bound})
        require(len(products) == 1 or self.random_streams == "per_product",
                f"the methods read {len(products)} products ({', '.join(products)}); set random_streams: per_product "
                "(each product its own random stream, one initiation prior shared by all)")
        for m in self.methods:
            tuned = m.tuned()
            if not tuned:
                continue
            require(self.tuning is not None, f"method {m.name!r}: option {tuned[0]} is 'tuned' but the scenario has "
                                             "no tuning section")
            points = 1
            for key in tuned:
                require(len(self.tuning.grid(key)) > 0, f"method {m.name!r}: option {key} is 'tuned' but "
                                                        f"tuning.{key}_grid is empty")
                points *= len(self.tuning.grid(key))
            require(points <= MAX_TUNING_POINTS, f"method {m.name!r}: {points} grid points to try, more than "
                                                 f"{MAX_TUNING_POINTS}; use smaller grids")

    def _check_case_overrides(self) -> None:
        """A case's ``methods`` (names of the scenario's methods, all if empty) and ``rd_maps``
        (keys of the scenario's ``rd_maps`` section it overrides, checked like the section)."""
        known = [m.name for m in self.methods]
        for c in self.cases:
            unknown = [n for n in c.methods if n not in known]
            require(not unknown, f"case {c.name!r}: methods {unknown} are not methods of the scenario "
                                 f"(methods: {', '.join(known)})")
            if c.rd_maps:
                require(self.rd_maps is not None, f"case {c.name!r} overrides rd_maps, but the scenario has no rd_maps "
                                                  "section")
                self.case_rd_maps(c)

    def case_methods(self, case: CaseSpec) -> tuple[MethodSpec, ...]:
        """The methods a case runs: those it names, or all."""
        return tuple(m for m in self.methods if not case.methods or m.name in case.methods)

    def case_rd_maps(self, case: CaseSpec) -> RDMapsSpec | None:
        """The scenario's ``rd_maps`` section with the case's overrides (nested sections merged key
        by key), checked like the section itself."""
        if self.rd_maps is None or not case.rd_maps:
            return self.rd_maps
        from ..config import to_dict

        def merged(base: dict, over: dict) -> dict:
            out = dict(base)
            for k, v in over.items():
                out[k] = merged(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
            return out

        return from_dict(RDMapsSpec, merged(to_dict(self.rd_maps), case.rd_maps), where=f"case {case.name!r}: rd_maps")

    def with_mc_runs(self, mc_runs: int | None) -> "Scenario":
        if mc_runs is None:
            return self
        return self.replace(mc_runs=mc_runs)

    def with_checkpoints(self, checkpoints: dict[str, str]) -> "Scenario":
        """Swap the checkpoint of named learned methods (``--checkpoint NAME=PATH``); the new
        paths are taken as given (relative to the working directory)."""
        by_name = {m.name: m for m in self.methods}
        for name in checkpoints:
            if name not in by_name:
                raise ConfigError(f"--checkpoint {name}=...: the scenario has no method {name!r} "
                                  f"(methods: {', '.join(by_name)})")
            if by_name[name].kind != "learned":
                raise ConfigError(f"--checkpoint {name}=...: {name!r} is a {by_name[name].kind}, not a learned method")
        methods = tuple(dataclasses.replace(m, checkpoint=str(Path(checkpoints[m.name]).resolve()))
                        if m.name in checkpoints else m for m in self.methods)
        return self.replace(methods=methods)

    def replace(self, **kw) -> "Scenario":
        try:
            new = dataclasses.replace(self, **kw)
        except ConfigError as exc:
            raise ConfigError(f"scenario {self.name!r}: {exc}") from None
        object.__setattr__(new, "base_dir", self.base_dir)
        return new

    def to_dict(self) -> dict:
        """Plain data; options added later (tuning, range outliers) are left out while off, so an
        older scenario's shard files stay as they were."""
        from ..config import to_dict

        d = to_dict(self)
        for key, off in (("tuning", None), ("detections", None), ("set_metrics", to_dict(SetMetricSpec())),
                         ("random_streams", "per_block"), ("rd_maps", None)):
            if d[key] == off:
                del d[key]
        for c in d["cases"]:  # an inline case is written as before; a multi-target one without the inline fields
            for k in FLIGHT_FIELDS if c["targets"] else ("targets",):
                c.pop(k, None)
            if c.get("segments") == []:
                del c["segments"]
            for key, off in (("end_s", None), ("methods", []), ("rd_maps", {})):
                if c[key] == off:
                    del c[key]
            for t in c.get("targets", []):  # the start as a position and velocity, only where given so
                for key in ("start_m", "velocity_mps", *FLIGHT_FIELDS):
                    if t.get(key, 0) is None:
                        del t[key]
        if d.get("reference") and d["reference"].get("subarea_table") is None:
            del d["reference"]["subarea_table"]
        if not self.noise.has_outliers and self.noise.range_outlier_scale == 10.0:
            del d["noise"]["range_outlier_prob"], d["noise"]["range_outlier_scale"]
        return d


FITEE2023_TRAJECTORIES = (
    CaseSpec("trajectory_1", 4000.0, 130.0, 10.0, 20.0, (SegmentSpec(1000.0),), "1: steady flight, 10 m/s"),
    CaseSpec("trajectory_2", 9000.0, 35.0, 5.0, 180.0, (SegmentSpec(1000.0, along_mps2=0.015),),
             "2: sustained acceleration, 5 to 20 m/s"),
    CaseSpec("trajectory_3", 7800.0, 140.0, 12.0, 0.0, (SegmentSpec(300.0), SegmentSpec(700.0, across_mps2=0.02)),
             "3: straight, then a 64-deg right turn"),
)
"""The three trajectories of ``evaluate/fitee2023_three_trajectories.yaml`` (a test keeps them
equal), built in so that ``pmsr demo`` needs no file."""


def scenario_from_dict(data: dict, base_dir: str | Path = ".", where: str = "scenario") -> Scenario:
    sc = from_dict(Scenario, data, where=where)
    object.__setattr__(sc, "base_dir", str(Path(base_dir).resolve()))
    return sc


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate a scenario YAML file (relative paths inside it are resolved against it)."""
    p = Path(path)
    return scenario_from_dict(load_yaml(p), p.parent, where=str(p))
