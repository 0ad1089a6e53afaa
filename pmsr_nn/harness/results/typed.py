"""What a report reads of a ``results.json``, typed: :meth:`Results.from_dict` builds it once.

The renderer (:mod:`pmsr_nn.harness.report.document` and its table and figure modules) reads these objects only, by
attribute; a part a row or case lacks is ``None`` (a bound's row has no set figures, a classical
row no finite-memory bound; the rows' types are in :mod:`.result_rows`). :meth:`Results.from_dict`
is the one place that reads the dict's layout: the result kind (``res["kind"]``: ``designed``
flights with a PCRB per case, or ``sampled`` multi-target truth), inferred there for files
written before that key existed.

Units as in ``results.json``: metres, metres per second, seconds; ``*_se*`` fields are Monte
Carlo standard errors over the runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from ...errors import ConfigError
from .result_rows import MethodRow, check_value, key_path, pick, table

KINDS = ("designed", "sampled")
"""``designed``: designed flights, a PCRB in every case; ``sampled``: truth sampled from a recipe."""


@dataclass(frozen=True)
class Pcrb:
    """A case's posterior Cramer-Rao bounds, averaged like ``rmse_pos_m`` (m, m/s)."""

    pos_m: float
    vel_mps: float | None = None
    smoothing_pos_m: float | None = None
    smoothing_vel_mps: float | None = None
    q0_pos_m: float | None = None
    q0_smoothing_pos_m: float | None = None


@dataclass(frozen=True)
class Spread:
    """Mean, min and max of a figure over training seeds."""

    mean: float
    min: float | None = None
    max: float | None = None


@dataclass(frozen=True)
class SeedGroup:
    """Learned rows ``BASE [seed k]`` summarised over their ``seeds`` training seeds."""

    seeds: int
    rmse_pos_m: Spread
    over_bound: Spread
    over_memory_bound: Spread | None = None

    @classmethod
    def from_dict(cls, g: dict, at: str) -> "SeedGroup":
        """The group of results.json's dict ``g`` (at ``at`` in the file); a missing key or one of
        the wrong type is a :class:`ConfigError` naming it."""
        for key in ("seeds", "rmse_pos_m", "over_bound"):
            if key not in table(g, at):
                raise ConfigError(f"{at}: lacks the key {key!r}")
        return pick(cls, g, at, rmse_pos_m=pick(Spread, g["rmse_pos_m"], key_path(at, "rmse_pos_m")),
                    over_bound=pick(Spread, g["over_bound"], key_path(at, "over_bound")),
                    over_memory_bound=pick(Spread, g.get("over_memory_bound"), key_path(at, "over_memory_bound")))


@dataclass(frozen=True)
class Comparison:
    """A learned tracker against the case's best ``classical`` row on the same runs: the mean over
    runs of (classical - learned) per-run position RMSE (m) and its standard error."""

    learned: str
    classical: str
    margin_m: float
    se_m: float


@dataclass(frozen=True)
class SetCurves:
    """Per-scan set figures of one row, means over runs: OSPA, GOSPA (m), number of tracks (and a
    PHD's integral)."""

    ospa_m: list
    cardinality: list
    gospa_m: list | None = None
    phd_expected: list | None = None


@dataclass(frozen=True)
class Curves:
    """Per-scan curves of a case: position RMSE per row (one list per target with several), the
    bounds (designed cases) and the set figures (cases scored as tracks)."""

    rmse_pos_m: dict
    pcrb_pos_m: list | None = None
    pcrb_smoothing_pos_m: list | None = None
    pcrb_q0_pos_m: list | None = None
    set: dict[str, SetCurves] | None = None
    cardinality_truth: list | None = None


@dataclass(frozen=True)
class Life:
    """A target's life in scans: from ``first_scan`` up to, not including, ``end_scan``."""

    name: str
    first_scan: int
    end_scan: int


@dataclass(frozen=True)
class StudyCase:
    """The settings of a multi-target study's case (the S-MSJPDA paper's layout)."""

    pd: float
    clutter_per_scan: float
    spacing_m: float | None = None
    formation: bool = True
    clutter_list: str = "sensor"
    reference_key: str | None = None
    detections_from: str | None = None


@dataclass(frozen=True)
class Case:
    """One case: its rows (name -> :class:`MethodRow`) and what the report draws of it."""

    name: str
    title: str
    methods: dict[str, MethodRow]
    steps: int | None = None
    targets: list = field(default_factory=list)
    lives: list[Life] = field(default_factory=list)
    pcrb: Pcrb | None = None
    curves: Curves | None = None
    seed_groups: dict[str, SeedGroup] = field(default_factory=dict)
    comparisons: list[Comparison] = field(default_factory=list)
    study: StudyCase | None = None
    rd_maps: dict | None = None
    front_end: dict | None = None
    set_comparisons: list | None = None  # :func:`~.paired.set_comparisons`

    @classmethod
    def from_dict(cls, name: str, c: dict, at: str = "") -> "Case":
        """Case ``name`` of results.json's dict ``c`` (at ``at`` in the file); an entry of the wrong
        type is a :class:`ConfigError` naming it (a hand-made case may lack any part, ``methods`` too)."""
        at = at or key_path("cases", name)
        table(c, at)
        for key, annotation in CASE_KEYS.items():
            if key in c:
                check_value(c[key], annotation, key_path(at, key))
        cv = c.get("curves")
        curves = None
        if cv is not None:
            if "rmse_pos_m" not in cv:
                raise ConfigError(f"case {name!r} has no curves.rmse_pos_m: a results.json of an older layout "
                                  "(re-run the scenario to report it)")
            sets, where = cv.get("set"), key_path(key_path(at, "curves"), "set")
            curves = pick(Curves, cv, key_path(at, "curves"), set=None if sets is None else {
                m: pick(SetCurves, s, key_path(where, m)) for m, s in table(sets, where).items()})
        groups = {b: SeedGroup.from_dict(g, key_path(key_path(at, "seed_groups"), b))
                  for b, g in (c.get("seed_groups") or {}).items()}
        rows = key_path(at, "methods")
        return cls(name=name, title=c.get("title", name), steps=c.get("steps"), targets=list(c.get("targets", [])),
                   methods={m: MethodRow.from_dict(r, key_path(rows, m)) for m, r in c.get("methods", {}).items()},
                   lives=[pick(Life, t, f"{key_path(at, 'lives')}[{i}]") for i, t in enumerate(c.get("lives", []))],
                   pcrb=pick(Pcrb, c.get("pcrb"), key_path(at, "pcrb")), curves=curves, seed_groups=groups,
                   comparisons=[pick(Comparison, k, f"{key_path(at, 'comparisons')}[{i}]")
                                for i, k in enumerate(c.get("comparisons") or [])],
                   study=pick(StudyCase, c, at) if "pd" in c else None, rd_maps=c.get("rd_maps"),
                   front_end=c.get("front_end"), set_comparisons=c.get("set_comparisons"))


CASE_KEYS = {"title": "str", "steps": "int | None", "targets": "list", "methods": "dict", "lives": "list",
             "pcrb": "dict | None", "curves": "dict | None", "seed_groups": "dict | None",
             "comparisons": "list | None", "rd_maps": "dict | None", "front_end": "dict | None",
             "set_comparisons": "list | None"}
"""The keys of a case that the typed case reads, with the type each admits."""


@dataclass(frozen=True)
class Tuning:
    """A grid search of a method's options on tracks of the training recipe: every point's position
    RMSE (m) and the chosen one."""

    options: list
    chosen: dict
    points: list
    rmse_pos_m: float
    seconds: float
    tracks: int
    steps: int
    recipe: str
    seed: int
    warmup_steps: int
    at_grid_edge: list = field(default_factory=list)


@dataclass(frozen=True)
class MethodSettings:
    """How a method was set up: its ``kind``, what it ``reads`` and its ``options`` as given;
    ``lists``: which detection lists it read where a single-frequency network pools them."""

    kind: str | None
    reads: str | None
    tuning: Tuning | None
    options: dict
    lists: str | None = None


@dataclass(frozen=True)
class SetMetric:
    """OSPA / GOSPA cut-off ``c_m`` (m) and order ``p``."""

    c_m: float
    p: float


@dataclass(frozen=True)
class Settings:
    """The settings the report reads: scan interval ``dt_s`` (s), warm-up (scans), Monte Carlo runs
    per block, the swept quantity (``none``), the divergence threshold (m) and the methods'
    set-ups. ``sections`` is the whole settings part of results.json, which the paragraph saying
    what was simulated quotes."""

    dt_s: float
    warmup_steps: int
    block_runs: int | None
    sweep: str
    divergence_m: float | None
    set_metrics: SetMetric | None
    methods: dict[str, MethodSettings]
    state_dim: int | None
    sections: dict

    @classmethod
    def from_dict(cls, st: dict, at: str = "settings") -> "Settings":
        table(st, at)
        for key, annotation in (("dt_s", "float"), ("warmup_steps", "int"), ("block_runs", "int | None"),
                                ("sweep", "str"), ("divergence_m", "float | None"), ("state_dim", "int | None"),
                                ("methods", "dict")):
            if key in st:
                check_value(st[key], annotation, key_path(at, key))
        where = key_path(at, "methods")
        methods = {}
        for m, s in st.get("methods", {}).items():
            w = key_path(where, m)
            table(s, w)
            for key in ("kind", "reads", "lists"):
                if key in s:
                    check_value(s[key], "str | None", key_path(w, key))
            methods[m] = MethodSettings(kind=s.get("kind"), reads=s.get("reads"), options=s, lists=s.get("lists"),
                                        tuning=pick(Tuning, s.get("tuning"), key_path(w, "tuning")))
        return cls(dt_s=st.get("dt_s", 1.0), warmup_steps=st.get("warmup_steps", 0), block_runs=st.get("block_runs"),
                   sweep=st.get("sweep", "none"), divergence_m=st.get("divergence_m"),
                   set_metrics=pick(SetMetric, st.get("set_metrics"), key_path(at, "set_metrics")), methods=methods,
                   state_dim=st.get("state_dim"), sections=st)


@dataclass(frozen=True)
class Results:
    """A scenario's results. ``kind``: :data:`KINDS`. The settings of a scenario with its own
    world (``settings["scans"]``) and those of a retired ``kind: multitarget`` study read alike."""

    scenario: str
    kind: Literal["designed", "sampled"]
    seed: int | None
    mc_runs: int
    settings: Settings
    cases: dict[str, Case]
    description: str | None = None
    definitions: dict = field(default_factory=dict)
    reference: dict = field(default_factory=dict)
    environment: dict = field(default_factory=dict)

    @classmethod
    def from_dict(cls, res: dict, source: str = "results") -> "Results":
        """The typed results of a ``results.json`` dict; a ``kind`` that is none of :data:`KINDS`
        (or a ``designed`` one with a case lacking its PCRB), an entry of the wrong type, a negative
        standard error or a missing ``cases`` is refused in one line, ``source: path.in.the.file:
        what``."""
        try:
            return cls._read(res)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None

    @classmethod
    def _read(cls, res: dict) -> "Results":
        if not isinstance(res, dict) or "cases" not in res:
            raise ConfigError("not a scenario's results.json (no 'cases' table)")
        for key, annotation in (("cases", "dict"), ("scenario", "str"), ("seed", "int | None"), ("mc_runs", "int"),
                                ("settings", "dict | None"), ("description", "str | None"),
                                ("definitions", "dict | None"), ("reference", "dict | None"),
                                ("environment", "dict | None")):
            if key in res:
                check_value(res[key], annotation, key)
        cases = {n: Case.from_dict(n, c) for n, c in res["cases"].items()}
        kind = res.get("kind")
        if kind in (None, "multitarget"):  # written before the key (or when it named the schema)
            kind = "designed" if all(c.pcrb is not None for c in cases.values()) else "sampled"
        elif kind not in KINDS:
            raise ConfigError(f"kind {kind!r} is none of {', '.join(KINDS)}")
        elif kind == "designed" and any(c.pcrb is None for c in cases.values()):
            bare = next(n for n, c in cases.items() if c.pcrb is None)
            raise ConfigError(f"kind 'designed' but case {bare!r} has no PCRB")
        settings = res.get("settings") or {}
        return cls(scenario=res.get("scenario", "?"), kind=kind, seed=res.get("seed"),
                   mc_runs=res.get("mc_runs", 0), settings=Settings.from_dict(settings), cases=cases,
                   description=res.get("description"), definitions=res.get("definitions") or {},
                   reference=res.get("reference") or {}, environment=res.get("environment") or {})

    @classmethod
    def of(cls, res: "Results | dict") -> "Results":
        """``res`` itself, or built from a results.json dict."""
        return res if isinstance(res, Results) else cls.from_dict(res)

    @property
    def designed(self) -> bool:
        """Designed flights, a PCRB in every case."""
        return self.kind == "designed"

    def rows(self):
        """``(case name, method name, row)`` over every case's rows, in order."""
        return ((c, m, r) for c, case in self.cases.items() for m, r in case.methods.items())
