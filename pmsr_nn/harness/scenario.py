"""Evaluation scenarios: what is simulated, how often, and which methods run on it (YAML).

A scenario names a dataset recipe (or takes the built-in one) (sensor geometry, motion model and
its q, sampling interval, Table 1 envelope), overrides its measurement noise with fixed
deviations, and lists

* ``cases``: fixed true trajectories (:class:`~.case_spec.CaseSpec`, flown by :mod:`.trajectories`),
  each seen by every method through the same ``mc_runs`` measurement-noise draws;
* ``methods``: classical filters, learned trackers and multi-target trackers with their settings
  (:class:`~.method_spec.MethodSpec`); an option of a classical filter set to ``tuned`` is chosen
  by a grid search on training tracks (``tuning``, :class:`~.method_spec.TuningSpec`, run by
  :mod:`.tuning`) before anything is written.

This module holds the scenario itself and its sensing sections (fixed noise, detections, set
metrics, the paper's reference tables) and :class:`StudyFile`, what every scenario kind shares
(a multi-target study, :mod:`.multitarget`, too). Takes plain YAML data; gives a frozen, checked
:class:`Scenario` (a bad field is refused in one line). Paths (recipe, checkpoints, reference
file) are relative to the scenario file.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from ..config import from_dict, load_yaml, require, to_dict
from ..errors import ConfigError
from ..methods import method_kind
from ..simulation.detections import ClutterSpec
from ..simulation.recipe import check_outliers
from ..tbd.scene import RDMapsSpec
from .case_spec import FLIGHT_FIELDS, MAX_CASE_DURATION_S, CaseSpec
from .method_spec import MAX_TUNING_POINTS, MethodSpec, TuningSpec

MAX_MC_RUNS = 10_000_000
"""Most Monte Carlo runs of a scenario (the papers use 100; per-run results are kept in memory)."""


@dataclass(frozen=True)
class DetectionSpec:
    """Detections for multi-target trackers: every transmitter-receiver pair detects each living
    target with probability ``pd`` per scan and reports clutter (:class:`ClutterSpec`, its box over
    ``components``); the noise is the scenario's fixed noise. ``illuminator_known`` false: a
    single-frequency network, each receiver reports one list per scan (its pairs' detections
    pooled, the transmitter of each unknown) and ``clutter.per_scan`` counts per receiver list
    (split evenly over its pairs); the kinds that read pooled lists (``pmht_3d``) read those,
    the others each pair's own list (the illuminator given)."""

    pd: float = 0.9
    clutter: ClutterSpec = ClutterSpec()
    components: tuple[str, ...] = ("range", "range_rate", "azimuth")
    illuminator_known: bool = True

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

    def with_mc_runs(self, mc_runs: int | None):
        """The same study with ``mc_runs`` runs (``None``: unchanged)."""
        if mc_runs is None:
            return self
        new = dataclasses.replace(self, mc_runs=mc_runs)
        object.__setattr__(new, "base_dir", self.base_dir)
        return new

    def with_seed(self, seed: int | None):
        """The same study drawn from ``seed`` (``--seed``; ``None``: unchanged): other truth and
        measurement draws, the same everything else."""
        if seed is None:
            return self
        new = dataclasses.replace(self, seed=seed)
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

    def with_seed(self, seed: int | None) -> "Scenario":
        if seed is None:
            return self
        return self.replace(seed=seed)

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


def scenario_from_dict(data: dict, base_dir: str | Path = ".", where: str = "scenario") -> Scenario:
    sc = from_dict(Scenario, data, where=where)
    object.__setattr__(sc, "base_dir", str(Path(base_dir).resolve()))
    return sc


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate a scenario YAML file (relative paths inside it are resolved against it)."""
    p = Path(path)
    return scenario_from_dict(load_yaml(p), p.parent, where=str(p))
