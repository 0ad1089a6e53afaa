"""Evaluation scenarios: what is simulated, how often, and which methods run on it (YAML).

A scenario names a dataset recipe (or takes the built-in one) (sensor geometry, motion model and
its q, sampling interval, Table 1 envelope), overrides its measurement noise with fixed
deviations, and lists

* ``cases``: fixed true trajectories (:class:`~.case_spec.CaseSpec`, flown by :mod:`.trajectories`),
  each seen by every method through the same ``mc_runs`` measurement-noise draws;
* or, with a ``world`` section (:class:`~.world.WorldSpec`) instead of a recipe, the scenario's own
  sensors and CV motion, cases of formations, listed states or designed aircraft, and trackers of
  detections (the multi-target studies: the S-MSJPDA paper's sweeps of Pd, clutter and spacing,
  ``sweep``, its track-loss rule, ``loss``);
* ``methods``: classical filters, learned trackers and multi-target trackers with their settings
  (:class:`~.method_spec.MethodSpec`); an option of a classical filter set to ``tuned`` is chosen
  by a grid search on training tracks (``tuning``, :class:`~.method_spec.TuningSpec`, run by
  :mod:`.tuning`) before anything is written.

This module holds the scenario itself and its sensing sections (fixed noise, detections, set
metrics, the paper's reference tables, the track-loss rule) and :class:`StudyFile`, what a
scenario file's runs share. Takes plain YAML data; gives a frozen, checked
:class:`Scenario` (a bad field is refused in one line). Paths (recipe, checkpoints, reference
file) are relative to the scenario file.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from ...config import from_dict, load_yaml, require, to_dict
from ...errors import ConfigError
from ...frontend.chain import FrontEndSpec
from ...methods import method_kind
from ...simulation.detections import ClutterSpec
from ...simulation.recipe import check_outliers
from ...tbd.scene import RDMapsSpec
from .case_spec import FLIGHT_FIELDS, MAX_CASE_DURATION_S, CaseSpec
from .method_spec import MAX_TUNING_POINTS, MethodSpec, TuningSpec
from .prepared import LossRule
from .world import WorldSpec

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
    the others each pair's own list (the illuminator given). ``front_end`` (a world scenario's):
    the detections come from simulated signals through that chain (range and Doppler; a
    range-rate deviation is converted through the carrier), ``pd``, ``clutter`` and the noise
    being then what the trackers assume."""

    pd: float = 0.9
    clutter: ClutterSpec = ClutterSpec()
    components: tuple[str, ...] = ("range", "range_rate", "azimuth")
    illuminator_known: bool = True
    front_end: FrontEndSpec | None = None

    def __post_init__(self) -> None:
        require(0 < self.pd <= 1, f"detections.pd must be in (0, 1], got {self.pd}")
        require(self.front_end is None or self.illuminator_known, "detections from signals (front_end) are per "
                                                                  "transmitter: set detections.illuminator_known true")
        allowed = ("range", "range_rate", "doppler", "azimuth")
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
    deviation is ``range_outlier_scale`` times ``range_m``. The filters' ``R`` is the nominal one.
    ``doppler_hz``: the Doppler deviation of a world scenario's detections (component ``doppler``)."""

    range_m: float = 30.0
    range_rate_mps: float = 2.0
    azimuth_deg: float = 3.0
    range_outlier_prob: float = 0.0
    range_outlier_scale: float = 10.0
    doppler_hz: float | None = None

    def __post_init__(self) -> None:
        require(min(self.range_m, self.range_rate_mps, self.azimuth_deg) > 0, "noise deviations must be positive")
        require(self.doppler_hz is None or (math.isfinite(self.doppler_hz) and self.doppler_hz > 0),
                f"noise doppler_hz must be positive, got {self.doppler_hz}")
        check_outliers("noise", self.range_outlier_prob, self.range_outlier_scale)

    @property
    def has_outliers(self) -> bool:
        return self.range_outlier_prob > 0

    def si(self) -> tuple[float, float, float]:
        return self.range_m, self.range_rate_mps, math.radians(self.azimuth_deg)

    def of(self, components: tuple[str, ...]) -> tuple[float, ...]:
        """The deviations of ``components`` (SI units, azimuth in rad)."""
        by_name = {"range": self.range_m, "range_rate": self.range_rate_mps, "azimuth": math.radians(self.azimuth_deg),
                   "doppler": self.doppler_hz}
        return tuple(by_name[c] for c in components)


@dataclass(frozen=True)
class ReferenceSpec:
    """Where the paper's numbers for this scenario are (dotted keys into ``file``): ``table`` maps
    case name -> method -> number (or method -> number for one case); ``timing`` run times
    (method -> milliseconds, or method -> case ``reference_key`` -> seconds per run);
    ``subarea_table`` a track-before-detect sub-area study's; ``velocity_rmse`` per-target velocity
    RMSE (paper method -> list) and ``anees`` per-target ANEES (a list, the paper's proposed method;
    its NEES not divided by the state dimension), ``methods`` mapping our method names to the
    paper's keys; ``setup`` the paper's stated set-up, shown beside the scenario's."""

    table: str | None = None
    file: str = "reference/paper_tables.json"
    timing: str | None = None
    label: str = "paper"
    subarea_table: str | None = None
    velocity_rmse: str | None = None
    anees: str | None = None
    methods: dict = field(default_factory=dict)
    setup: str | None = None

    def __post_init__(self) -> None:
        require(any(k is not None for k in (self.table, self.subarea_table, self.timing, self.velocity_rmse,
                                             self.anees, self.setup)),
                "reference needs a table (or a timing, subarea_table, velocity_rmse, anees or setup key)")


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
    divergence_m: float | None = 1000.0
    ramp_s: float = 60.0
    reference: ReferenceSpec | None = None
    tuning: TuningSpec | None = None
    detections: DetectionSpec | None = None
    set_metrics: SetMetricSpec = SetMetricSpec()
    random_streams: Literal["per_block", "per_product"] = "per_block"
    description: str = ""
    rd_maps: RDMapsSpec | None = None
    world: WorldSpec | None = None
    loss: LossRule | None = None
    sweep: Literal["none", "pd", "clutter_per_scan", "spacing_m"] = "none"
    base_dir: str = field(default=".", init=False, compare=False)

    def __post_init__(self) -> None:
        require(self.seed >= 0, f"seed must be non-negative, got {self.seed}")
        self._check_case_overrides()
        if self.world is not None:
            self._check_world()
        else:
            worldly = [c.name for c in self.cases if c.in_world or c.detections or c.prior is not None]
            require(not worldly, f"case(s) {worldly}: formation, states, aircraft, detections and prior are cases of "
                                 "a world section (the scenario has none)")
            require(self.detections is None or ("doppler" not in self.detections.components
                                                and self.detections.front_end is None),
                    "detections.components doppler and detections.front_end need a world section")
            require(self.sweep == "none", "sweep needs a world section (cases that vary pd, clutter or spacing)")
        require(1 <= self.mc_runs <= MAX_MC_RUNS, f"mc_runs must be in [1, {MAX_MC_RUNS:,}], got {self.mc_runs:,}")
        require(self.block_runs >= 1, f"block_runs must be at least 1, got {self.block_runs}")
        require(self.warmup_steps >= 0, f"warmup_steps must be >= 0, got {self.warmup_steps}")
        require(self.divergence_m is None or self.divergence_m > 0,
                f"divergence_m must be positive (or null: no divergence count), got {self.divergence_m}")
        require(self.ramp_s >= 0, f"ramp_s must be >= 0, got {self.ramp_s}")
        require(len(self.cases) > 0, "a scenario needs at least one case")
        require(len(self.methods) > 0, "a scenario needs at least one method")
        for c in self.cases:
            if c.in_world:
                continue
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
        require(len(products) <= 1 or self.random_streams == "per_product",
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

    def _check_world(self) -> None:
        """A world scenario: no recipe, trackers of detections, every case's targets in the world
        (of its dimensions), each case's detections and the sweep well formed."""
        w = self.world
        require(self.recipe is None, "give the sensors and motion as a recipe or a world section, not both")
        require(self.detections is not None, "a world scenario needs a detections section (pd, clutter, components)")
        require(self.tuning is None and self.rd_maps is None, "tuning and rd_maps need a recipe (no world section)")
        require(self.random_streams == "per_block", "a world scenario's trackers all read detections: random_streams "
                                                    "per_block")
        for m in self.methods:
            require(method_kind(m.kind).reads == "detections", f"method {m.name!r}: kind {m.kind} reads "
                                                               f"{method_kind(m.kind).reads}; a world scenario runs "
                                                               "trackers of detections")
        require(self.warmup_steps < w.scans, f"warmup_steps {self.warmup_steps} must be below world.scans ({w.scans})")
        require("doppler" not in self.detections.components or self.noise.doppler_hz is not None,
                "detections.components has doppler: give noise.doppler_hz")
        for c in self.cases:
            require(c.in_world, f"case {c.name!r}: a world case gives its targets as formation, states or aircraft")
            for i, t in enumerate(c.states):
                require(len(t.position_m) == w.dimensions, f"case {c.name!r}: states[{i}] is {len(t.position_m)}-D in a "
                                                           f"{w.dimensions}-D world")
            require(w.dimensions == 2 or not c.formation, f"case {c.name!r}: a formation flies in 2-D (world.dimensions "
                                                          "2); list 3-D targets in states or aircraft")
            require(not c.aircraft or w.dimensions == 3, f"case {c.name!r}: aircraft fly in 3-D: set world.dimensions 3")
            require(self.sweep != "spacing_m" or c.formation, f"case {c.name!r}: a spacing_m sweep needs a formation")
            fe = self.case_detections(c).front_end
            require(fe is None or all(k < w.scans for k in fe.example_scans),
                    f"case {c.name!r}: front_end example_scans {list(fe.example_scans) if fe else []} must be below "
                    f"world.scans ({w.scans})")

    def case_detections(self, case: CaseSpec) -> DetectionSpec | None:
        """The scenario's detections section with the case's overrides (nested sections merged key
        by key), checked like the section itself."""
        if self.detections is None or not case.detections:
            return self.detections
        return from_dict(DetectionSpec, _merged(to_dict(self.detections), case.detections),
                         where=f"case {case.name!r}: detections")

    def case_methods(self, case: CaseSpec) -> tuple[MethodSpec, ...]:
        """The methods a case runs: those it names, or all."""
        return tuple(m for m in self.methods if not case.methods or m.name in case.methods)

    def case_rd_maps(self, case: CaseSpec) -> RDMapsSpec | None:
        """The scenario's ``rd_maps`` section with the case's overrides (nested sections merged key
        by key), checked like the section itself."""
        if self.rd_maps is None or not case.rd_maps:
            return self.rd_maps
        return from_dict(RDMapsSpec, _merged(to_dict(self.rd_maps), case.rd_maps), where=f"case {case.name!r}: rd_maps")

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
        paths are taken as given (relative to the working directory). Any kind that reads a
        checkpoint (``learned``, ``nebp``) takes one."""
        from ...methods import registry

        kinds = registry()
        by_name = {m.name: m for m in self.methods}
        for name in checkpoints:
            if name not in by_name:
                raise ConfigError(f"--checkpoint {name}=...: the scenario has no method {name!r} "
                                  f"(methods: {', '.join(by_name)})")
            kind = kinds.get(by_name[name].kind)
            if kind is None or not kind.needs_checkpoint:
                raise ConfigError(f"--checkpoint {name}=...: {name!r} is a {by_name[name].kind}, which reads no checkpoint")
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
                         ("random_streams", "per_block"), ("rd_maps", None), ("world", None), ("loss", None),
                         ("sweep", "none")):
            if d[key] == off:
                del d[key]
        if d.get("detections") and d["detections"]["front_end"] is None:
            del d["detections"]["front_end"]
        for c in d["cases"]:  # an inline case is written as before; a multi-target one without the inline fields
            for k in FLIGHT_FIELDS if c["targets"] or self.world else ("targets",):
                c.pop(k, None)
            if c.get("segments") == []:
                del c["segments"]
            for key, off in (("end_s", None), ("methods", []), ("rd_maps", {}), ("formation", None), ("states", []),
                             ("aircraft", []), ("detections", {}), ("prior", None), ("reference_key", None)):
                if c[key] == off:
                    del c[key]
            for t in c.get("targets", []):  # the start as a position and velocity, only where given so
                for key in ("start_m", "velocity_mps", *FLIGHT_FIELDS):
                    if t.get(key, 0) is None:
                        del t[key]
        if d.get("reference"):
            for key, off in (("subarea_table", None), ("velocity_rmse", None), ("anees", None), ("methods", {}),
                             ("setup", None)):
                if d["reference"][key] == off:
                    del d["reference"][key]
        if not self.noise.has_outliers and self.noise.range_outlier_scale == 10.0:
            del d["noise"]["range_outlier_prob"], d["noise"]["range_outlier_scale"]
        if self.noise.doppler_hz is None:
            del d["noise"]["doppler_hz"]
        return d


def _merged(base: dict, over: dict) -> dict:
    """``base`` with ``over``'s keys, nested dicts merged key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = _merged(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


RETIRED_KINDS = {
    "multitarget": "'kind: multitarget' scenarios are retired: drop the kind and write the study as a scenario "
                   "with a world section (scans, geometry, motion, prior), detections (pd, clutter, components "
                   "[range, doppler], illuminator_known, front_end), loss, warmup_steps for converged_from_scan, the "
                   "targets per case (formation, states or aircraft) and the tracker options per method (e.g. "
                   "evaluate/access2019_msjpda.yaml)",
    "tbd": "'kind: tbd' study files are gone: the track-before-detect filters are method kinds (pmb, icmb, "
           "modified_icmb, detect_then_track) of a scenario with an rd_maps section (e.g. "
           "evaluate/remotesensing2020_icmb.yaml)",
    "phd": "'kind: phd' study files are gone: the SMC-PHD of one pair's bistatic plane is method kind smc_phd_pair "
           "(labelling gtda | hungarian | none) of a scenario with a world section and aircraft (e.g. "
           "evaluate/daniyan_smcphd.yaml)",
}
"""What a scenario file of a retired ``kind`` is told (one line each)."""


def scenario_from_dict(data: dict, base_dir: str | Path = ".", where: str = "scenario") -> Scenario:
    """A checked :class:`Scenario` from plain data (a retired ``kind`` refused in one line)."""
    if isinstance(data, dict) and data.get("kind") in RETIRED_KINDS:
        raise ConfigError(f"{where}: {RETIRED_KINDS[data['kind']]}")
    cases = data.get("cases") if isinstance(data, dict) else None
    for i, c in enumerate(cases if isinstance(cases, list) else []):
        if not isinstance(c, dict):
            continue
        empty = [k for k in ("targets", "states", "aircraft") if c.get(k) == []]
        given = any(c.get(k) for k in ("targets", "states", "aircraft", "formation")) or \
            any(c.get(k) is not None for k in FLIGHT_FIELDS)
        if empty and not given:  # else the case reads as one inline flight with its fields missing
            raise ConfigError(f"{where}.cases[{i}]: case {c.get('name', '?')!r}: {empty[0]}: [] lists no target; "
                              "give at least one")
    sc = from_dict(Scenario, data, where=where)
    object.__setattr__(sc, "base_dir", str(Path(base_dir).resolve()))
    return sc


def load_scenario(path: str | Path) -> Scenario:
    """Load and validate a scenario YAML file (relative paths inside it are resolved against it)."""
    p = Path(path)
    return scenario_from_dict(load_yaml(p), p.parent, where=str(p))
