"""One method's figures in one case of a ``results.json``, typed (:class:`MethodRow`), with its
optional parts: its bound, finite-memory bound, set and track figures, estimate space and
track-before-detect figures (None where the row has none).

Units as in ``results.json``: metres, metres per second, seconds; ``*_se*`` fields are Monte
Carlo standard errors over the runs.
"""

from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass

from ...errors import ConfigError

_TYPES = {"float": ("a number", lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)),
          "int": ("an integer", lambda v: isinstance(v, int) and not isinstance(v, bool)),
          "bool": ("true or false", lambda v: isinstance(v, bool)),
          "str": ("a string", lambda v: isinstance(v, str)),
          "list": ("a list", lambda v: isinstance(v, (list, tuple))),
          "dict": ("a table", lambda v: isinstance(v, dict))}
"""What a field's annotation admits, in words and as a test (a bool is not a number)."""

STANDARD_ERROR = re.compile(r"(^|_)se(_|$)")
"""Names of the fields holding a Monte Carlo standard error (never negative)."""


def key_path(at: str, key) -> str:
    """Where entry ``key`` of the part at ``at`` sits in results.json: ``cases['c'].methods``."""
    key = key if isinstance(key, str) and key.isidentifier() else f"[{key!r}]"
    return key if not at else f"{at}{key}" if key.startswith("[") else f"{at}.{key}"


def shown(value) -> str:
    """``value`` as JSON writes it, cut to 40 characters (an error line stays one short line)."""
    try:
        text = json.dumps(value, allow_nan=True)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def check_value(value, annotation: str, at: str) -> None:
    """Refuse (:class:`ConfigError`, one line naming ``at``) a ``value`` that is not of
    ``annotation`` (a field's, e.g. ``"float | None"``; a dataclass part is checked where it is
    built), or a negative standard error."""
    names = [a.strip() for a in str(annotation).split("|")]
    known = [n for n in names if n in _TYPES]
    if (value is None and "None" in names) or not known:
        return
    if not any(_TYPES[n][1](value) for n in known):
        words = " or ".join([_TYPES[n][0] for n in known] + (["null"] if "None" in names else []))
        raise ConfigError(f"{at}: expected {words}, got {shown(value)}")
    if known == ["float"] and STANDARD_ERROR.search(at.rsplit(".", 1)[-1]) and value < 0:
        raise ConfigError(f"{at}: expected a non-negative number, got {shown(value)}")


def table(d, at: str) -> dict:
    """``d`` when it is a table (a JSON object), else a one-line :class:`ConfigError` naming ``at``."""
    if not isinstance(d, dict):
        raise ConfigError(f"{at}: expected a table, got {shown(d)}")
    return d


def pick(cls, d: dict | None, at: str = "", **given):
    """``cls`` from the entries of ``d`` named like its fields (absent ones take their default),
    with ``given`` fields set as passed; None for a missing ``d``. ``at``: where ``d`` sits in
    results.json; an entry of the wrong type, or a field without default that ``d`` lacks, is a
    :class:`ConfigError` naming it."""
    if d is None:
        return None
    table(d, at)
    kept = {}
    for f in dataclasses.fields(cls):
        if f.name in given:
            continue
        if f.name in d:
            check_value(d[f.name], f.type, key_path(at, f.name))
            kept[f.name] = d[f.name]
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{at or 'results'}: lacks the key {f.name!r}")
    return cls(**kept, **given)


@dataclass(frozen=True)
class BoundComparison:
    """A row against its case's PCRB (filtering for a causal row, smoothing for one that looks
    ahead) and the bound with q = 0 (the floor). ``mse_ratio``: mean over runs of the run's mean
    squared position error over the bound's mean square, ``mse_ratio_se`` its standard error;
    ``below``: under 1 beyond that error (the runner's one-sided 97.5 % Student-t rule)."""

    which: str
    pos_m: float | None
    over: float | None = None
    mse_ratio: float | None = None
    mse_ratio_se: float | None = None
    below: bool = False
    q0_pos_m: float | None = None
    q0_mse_ratio: float | None = None
    q0_mse_ratio_se: float | None = None
    below_q0: bool = False


@dataclass(frozen=True)
class MemoryBound:
    """A causal learned row against the filtering PCRB of only the ``scans`` scans it reads."""

    scans: int
    pos_m: float
    over: float
    mse_ratio: float
    mse_ratio_se: float
    below: bool


RUN_QUANTILES = (0.25, 0.5, 0.75, 0.9, 1.0)
"""Where over the runs ``SetFigures.gospa_run_quantiles_m`` reads each run's GOSPA: the quartiles,
the 90 % point and the worst run."""


@dataclass(frozen=True)
class SetFigures:
    """Multi-target figures of a row that reports tracks (m; shares of GOSPA^p add up to 1)."""

    ospa_m: float
    gospa_m: float | None = None
    gospa_localisation_share: float | None = None
    gospa_missed_share: float | None = None
    gospa_false_share: float | None = None
    cardinality_mean_abs_error: float | None = None
    rmse_pos_assigned_per_target_m: list | None = None
    label_switches_per_run: float | None = None
    label_switches_per_target: list | None = None
    id_switches_per_run: float | None = None  # CLEAR MOT identity switches (None: not recorded)
    id_switches_per_target: list | None = None
    ospa_se_m: float | None = None
    gospa_se_m: float | None = None
    gospa_median_run_m: float | None = None
    gospa_run_quantiles_m: list | None = None  # at RUN_QUANTILES
    tgospa_m: float | None = None  # trajectory GOSPA per set scan (None: not recorded, or no identities)
    tgospa_se_m: float | None = None
    tgospa_gamma_m: float | None = None
    tgospa_localisation_share: float | None = None
    tgospa_missed_share: float | None = None
    tgospa_false_share: float | None = None
    tgospa_switching_share: float | None = None
    tgospa_switches_per_run: float | None = None
    tgospa_integral_runs: int | None = None


@dataclass(frozen=True)
class TrackFigures:
    """Track-level figures: tracks matched to the living targets scan by scan."""

    confirmed_tracks_per_target: float | None = None
    false_tracks_per_run: float | None = None
    missed_target_fraction: float | None = None
    scans_to_first_track: float | None = None
    track_loss_probability: float | None = None
    fragmentations_per_run: float | None = None
    fragmentations_per_target: list | None = None
    runs_without_tracks: int | None = None  # runs with no reported track at all (None: not recorded)


@dataclass(frozen=True)
class PlaneSpace:
    """A row scored in one pair's bistatic plane: its ``position`` is bistatic range (m), its
    ``velocity`` range-rate (m/s)."""

    title: str
    key: str
    position: str
    velocity: str
    rmse_vel_pooled_mps: float | None


@dataclass(frozen=True)
class TbdFigures:
    """Per-frame figures of a row that reads range-Doppler maps (:class:`~pmsr_nn.methods.kind_metrics.TBDFrames`);
    lists have one entry per frame (``snr_db``: per frame and map)."""

    update: str
    snr: str
    subarea: str | None
    power_ratio: float | None
    detected_frame_rate: list
    detected_rate_present: float
    false_alarm_rate_absent: float | None
    detected_rate_table_frame: float
    rms_pos_m: list
    rms_vel_mps: list
    rms_pos_last_present_m: float
    rms_vel_last_present_mps: float
    median_pos_err_m: list
    median_pos_err_last_present_m: float
    existence: list
    ospa_frame_m: list
    ospa_mean_m: float
    snr_db: list
    targets_held_rate: float | None = None  # absent from records made before it
    unassigned_tracks_per_frame: float | None = None


@dataclass(frozen=True)
class MethodRow:
    """One method's figures in one case. ``rmse_pos_m`` follows Eq. 31 of the MDFNN paper (after
    the warm-up); with several targets the ``*_per_target_*`` lists hold one entry per target."""

    kind: str | None = None
    causal: bool | None = None
    initiation: str | None = None
    rmse_pos_m: float | None = None
    rmse_vel_mps: float | None = None
    anees: float | None = None
    seconds_per_run: float | None = None
    rmse_pos_pooled_m: float | None = None
    rmse_pos_all_scans_m: float | None = None
    median_run_rmse_pos_m: float | None = None
    runs: int | None = None
    rmse_pos_se_m: float | None = None
    rmse_pos_per_target_m: list | None = None
    rmse_vel_per_target_mps: list | None = None
    anees_per_target: list | None = None
    diverged_runs: int | None = None
    loss_probability: float | None = None
    swap_probability: float | None = None
    max_duality_gap: float | None = None
    labels_per_run: float | None = None
    phd_seconds_per_run: float | None = None
    labelled: bool = True
    bound: BoundComparison | None = None
    memory: MemoryBound | None = None
    sets: SetFigures | None = None
    tracks: TrackFigures | None = None
    space: PlaneSpace | None = None
    tbd: TbdFigures | None = None

    @classmethod
    def from_dict(cls, r: dict, at: str = "") -> "MethodRow":
        """The row of results.json's dict ``r`` (at ``at`` in the file): an entry of the wrong
        type or a negative standard error is a :class:`ConfigError` (a hand-made row may lack
        any figure; :mod:`.compare` asks for the position RMSE every written row has)."""
        table(r, at)
        for key, annotation in ROW_KEYS.items():
            if key in r:
                check_value(r[key], annotation, key_path(at, key))

        def need(key, part):  # a part's other keys, where its first one is there
            if key not in r:
                raise ConfigError(f"{at or 'results'}: lacks the key {key!r} (it has {part!r})")
            return r[key]

        bound = None
        if "bound" in r:
            bound = BoundComparison(
                which=r["bound"], pos_m=r.get("bound_pos_m"), over=r.get("over_bound"),
                mse_ratio=r.get("mse_over_bound"), mse_ratio_se=r.get("mse_over_bound_se"),
                below=bool(r.get("below_bound")), q0_pos_m=r.get("bound_q0_pos_m"),
                q0_mse_ratio=r.get("mse_over_q0_bound"), q0_mse_ratio_se=r.get("mse_over_q0_bound_se"),
                below_q0=bool(r.get("below_q0_bound")))
        elif r.get("below_bound"):  # a flag without its bound's name (a hand-made row)
            bound = BoundComparison(which="filtering", pos_m=None, mse_ratio=r.get("mse_over_bound"),
                                    mse_ratio_se=r.get("mse_over_bound_se"), below=True,
                                    below_q0=bool(r.get("below_q0_bound")))
        memory = None
        if "memory_bound_pos_m" in r:
            m = "memory_bound_pos_m"
            memory = MemoryBound(scans=need("memory_scans", m), pos_m=r[m], over=need("over_memory_bound", m),
                                 mse_ratio=need("mse_over_memory_bound", m),
                                 mse_ratio_se=need("mse_over_memory_bound_se", m),
                                 below=bool(need("below_memory_bound", m)))
        space = None
        if r.get("space_key"):
            space = PlaneSpace(title=need("space", "space_key"), key=r["space_key"],
                               position=need("position", "space_key"), velocity=need("velocity", "space_key"),
                               rmse_vel_pooled_mps=r.get("rmse_vel_pooled_mps"))
        tracks = pick(TrackFigures, r, at) if "confirmed_tracks_per_target" in r else None
        return pick(cls, r, at, bound=bound, memory=memory, space=space, tracks=tracks,
                    sets=pick(SetFigures, r, at) if "ospa_m" in r else None,
                    tbd=pick(TbdFigures, r.get("tbd"), key_path(at, "tbd")))

    @property
    def below_bound(self) -> bool:
        """Under its bound beyond the Monte Carlo error, as the results say."""
        return self.bound is not None and self.bound.below

    @property
    def below_bound_unsure(self) -> bool:
        """Flagged under its bound by results that hold no standard error for it (written before it was kept)."""
        return self.below_bound and self.bound.mse_ratio_se is None

ROW_KEYS = {
    **{f.name: f.type for part in (SetFigures, TrackFigures) for f in dataclasses.fields(part)},
    **{f.name: f.type for f in dataclasses.fields(MethodRow)
       if f.name not in ("bound", "memory", "sets", "tracks", "space", "tbd")},
    "bound": "str", "bound_pos_m": "float | None", "over_bound": "float | None", "mse_over_bound": "float | None",
    "mse_over_bound_se": "float | None", "below_bound": "bool", "bound_q0_pos_m": "float | None",
    "mse_over_q0_bound": "float | None", "mse_over_q0_bound_se": "float | None", "below_q0_bound": "bool",
    "memory_scans": "int", "memory_bound_pos_m": "float", "over_memory_bound": "float",
    "mse_over_memory_bound": "float", "mse_over_memory_bound_se": "float", "below_memory_bound": "bool",
    "space": "str", "space_key": "str", "position": "str", "velocity": "str", "rmse_vel_pooled_mps": "float | None",
    "tbd": "dict | None",
}
"""Every key of a row that the typed row reads, with the type it admits (results.json's names)."""
