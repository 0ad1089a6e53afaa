"""SMC-PHD studies (``kind: phd``): an unknown, varying number of aircraft, one SMC-PHD filter,
its estimates labelled by GTDA and by the Hungarian baseline, on the same Monte Carlo draws.

The Daniyan seed's Section III-IV (a field recording we do not have, simulated to its stated
set-up): one FM transmitter and one receiver, designed aircraft flights
(:mod:`pmsr_nn.simulation.aircraft`) seen above a minimum altitude and inside a maximum
bistatic range, detections (bistatic range, range-rate) with Pd and clutter from the package's
detection model (:func:`~pmsr_nn.simulation.detections.simulate_scans`). Per case (Pd, clutter)
and block of runs: the detections from a generator seeded by ``(seed, case, block)``, the PHD
filter once (its own stream), then each method's labelling of the same PHD estimates (one
stream per method). Nobody is told how many aircraft there are or where they start.

Scoring, in the bistatic plane ``[r, rdot]`` (the trackers' state), per scan:

* OSPA / GOSPA (cut-off ``set_metrics.c_m``, order ``p``) on the bistatic range of the
  estimates: one axis, in metres; range-rate errors are reported separately, over the pairs the
  OSPA assignment matches;
* the cardinality: true, the PHD's integral, the PHD's estimates, each method's tracks;
* per target and run: label switches and fragmentations (:mod:`pmsr_nn.metrics.sets`) of each
  labelled output, and the labels a run starts.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from ..config import from_dict, require, to_dict
from ..environment import environment
from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..metrics import fragmentations, label_switches, set_scores
from ..rng import seeded_generator
from ..simulation.aircraft import AircraftSpec, fly_all
from ..simulation.detections import ClutterSpec, simulate_scans
from ..frontend.chain import FrontEndSpec
from ..measurements import SPEED_OF_LIGHT
from ..simulation.recipe import GeometrySpec, ReceiverSpec, TransmitterSpec
from ..trackers.gtda import GameSpec
from ..trackers.labelling import LabelSpec, label_tracks
from ..trackers.phd import PHDSpec, SMCPHD
from .scenario import SetMetricSpec, StudyFile

PHD = "smcphd"
"""The name of the unlabelled PHD estimates in the results (a row beside the labelled methods)."""

KNOWN = "known_association_kf"
"""The reference row: a Kalman filter per aircraft on exactly its own detections, births known."""


@dataclass(frozen=True)
class PHDMethodSpec:
    """A labelling of the PHD estimates: ``labelling`` ``gtda`` or ``hungarian``; ``options``
    overrides the study's ``labelling`` settings (``gate_probability``, ``max_missed``,
    ``confirm_m``, ``confirm_n``, and for GTDA ``forgetting``, ``iterations``, ``conflict``,
    ``alpha_scale``)."""

    name: str
    labelling: Literal["gtda", "hungarian"] = "gtda"
    options: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        require(bool(self.name) and "/" not in self.name and self.name not in (PHD, KNOWN),
                f"method name {self.name!r} must be non-empty, without '/', and not {PHD!r} or {KNOWN!r}")


@dataclass(frozen=True)
class PHDCaseSpec:
    """A setting: ``pd`` and ``clutter_per_scan`` override the study's; ``detections_csv`` replaces
    the simulated detections by a file of your own (e.g. a recording's centroided CFAR detections,
    the seed's workflow): columns ``scan`` (0-based), ``range_m``, ``range_rate_mps``, one row per
    detection. Every run then reads the same detections (the runs differ in the filter's own
    draws) and is scored against the study's flights; ``pd`` and ``clutter_per_scan`` are then
    the filter's assumptions. ``signals: true`` takes the detections from the study's FM
    ``front_end`` signal chain instead (samples, cancellation, 2D-CCF, OS-CFAR, centroids; its
    Doppler turned into range-rate), Pd and clutter again the filter's assumptions. ``noise``
    overrides the study's deviations for this case (the filter's, and the simulation's)."""

    name: str
    title: str = ""
    pd: float | None = None
    clutter_per_scan: float | None = None
    detections_csv: str | None = None
    signals: bool = False
    noise: "BistaticNoiseSpec | None" = None


CSV_COLUMNS = ("scan", "range_m", "range_rate_mps")


def read_detections_csv(path: Path, scans: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Detections ``z (scans, J, 2)`` (NaN padding) and ``valid (scans, J)`` from a CSV file
    (:class:`PHDCaseSpec`); a one-line :class:`ConfigError` for a missing file, a wrong header, a
    scan outside the study or a value that is not a finite number."""
    import csv

    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"detections_csv {path}: can not be read ({type(exc).__name__})") from None
    if not rows or tuple(c.strip() for c in rows[0]) != CSV_COLUMNS:
        raise ConfigError(f"detections_csv {path}: the first line must be the header {','.join(CSV_COLUMNS)}")
    per_scan: list[list[tuple[float, float]]] = [[] for _ in range(scans)]
    for line, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        if len(row) != 3:
            raise ConfigError(f"detections_csv {path} line {line}: 3 values expected, got {len(row)}")
        try:
            k = int(row[0])
            r, v = float(row[1]), float(row[2])
        except ValueError:
            raise ConfigError(f"detections_csv {path} line {line}: {row!r} is not an integer scan and two numbers") from None
        bad = [n for n, x in zip(CSV_COLUMNS[1:], (r, v)) if not math.isfinite(x)]
        if bad:
            raise ConfigError(f"detections_csv {path} line {line}: {bad[0]} is not a finite number (NaN or inf)")
        if not 0 <= k < scans:
            raise ConfigError(f"detections_csv {path} line {line}: scan {k} is outside the study's 0..{scans - 1}")
        per_scan[k].append((r, v))
    J = max(1, max(len(d) for d in per_scan))
    z = torch.full((scans, J, 2), float("nan"), dtype=torch.float64)
    valid = torch.zeros(scans, J, dtype=torch.bool)
    for k, d in enumerate(per_scan):
        if d:
            z[k, : len(d)] = torch.tensor(d, dtype=torch.float64)
            valid[k, : len(d)] = True
    return z, valid


@dataclass(frozen=True)
class BistaticNoiseSpec:
    """Detection deviations: bistatic range (m) and range-rate (m/s); the seed's 30 m and 4.5 m/s."""

    range_m: float = 30.0
    range_rate_mps: float = 4.5

    def __post_init__(self) -> None:
        require(self.range_m > 0 and self.range_rate_mps > 0, "noise deviations must be positive")


@dataclass(frozen=True)
class LabellingSpec:
    """The labelling settings every method starts from (:class:`~pmsr_nn.trackers.labelling.LabelSpec`):
    a new track is labelled once it took an estimate in ``confirm_m`` of its first ``confirm_n`` scans."""

    gate_probability: float = 0.999
    max_missed: int = 3
    confirm_m: int = 1
    confirm_n: int = 1
    game: GameSpec = GameSpec()


@dataclass(frozen=True)
class PHDReferenceSpec:
    file: str = "reference/paper_tables.json"
    key: str = "daniyan_gtda.setup"
    label: str = "seed"


DEFAULT_GEOMETRY = GeometrySpec(transmitters=(TransmitterSpec((6500.0, 0.0), 106.0e6),),
                                receivers=(ReceiverSpec(position_m=(0.0, 0.0)),))
"""The seed's set-up: an FM transmitter (106 MHz) 6.5 km from the receiver."""

DEFAULT_CLUTTER = ClutterSpec(per_scan=10.0, model="poisson", range_m=(6500.0, 48_000.0),
                              range_rate_mps=(-500.0, 500.0))


@dataclass(frozen=True)
class PHDScenario(StudyFile):
    name: str
    aircraft: tuple[AircraftSpec, ...]
    cases: tuple[PHDCaseSpec, ...]
    methods: tuple[PHDMethodSpec, ...]
    kind: Literal["phd"] = "phd"
    description: str = ""
    seed: int = 0
    mc_runs: int = 10
    block_runs: int = 5
    duration_s: float = 732.0
    dt_s: float = 1.0
    geometry: GeometrySpec = DEFAULT_GEOMETRY
    noise: BistaticNoiseSpec = BistaticNoiseSpec()
    pd: float = 0.9
    clutter: ClutterSpec = DEFAULT_CLUTTER
    min_altitude_m: float = 100.0
    max_range_m: float = 48_000.0
    phd: PHDSpec = PHDSpec()
    labelling: LabellingSpec = LabellingSpec()
    front_end: FrontEndSpec | None = None
    set_metrics: SetMetricSpec = SetMetricSpec()
    reference: PHDReferenceSpec | None = None
    base_dir: str = field(default=".", init=False, compare=False)

    def __post_init__(self) -> None:
        require(1 <= self.mc_runs <= 1_000_000 and self.block_runs >= 1, "mc_runs must be in [1, 1e6], block_runs >= 1")
        require(self.seed >= 0, f"seed must be >= 0, got {self.seed}")
        require(self.dt_s > 0 and self.duration_s >= 2 * self.dt_s, "duration_s must cover at least two scans of dt_s > 0")
        require(len(self.aircraft) > 0 and len(self.cases) > 0 and len(self.methods) > 0,
                "a study needs aircraft, cases and methods")
        require(len(self.geometry.transmitters) == 1 and len(self.geometry.receivers) == 1,
                "an SMC-PHD study tracks in one bistatic plane: give one transmitter and one receiver")
        require(0 < self.pd <= 1, f"pd must be in (0, 1], got {self.pd}")
        for what, names in (("case", [c.name for c in self.cases]), ("method", [m.name for m in self.methods]),
                            ("aircraft", [a.name for a in self.aircraft])):
            dup = sorted({n for n in names if names.count(n) > 1})
            require(not dup, f"duplicate {what} name(s): {dup}")
        for c in self.cases:
            require(c.pd is None or 0 < c.pd <= 1, f"case {c.name!r}: pd must be in (0, 1], got {c.pd}")
            require(c.clutter_per_scan is None or 0 <= c.clutter_per_scan <= 100_000,
                    f"case {c.name!r}: clutter_per_scan must be in [0, 100000]")
            require(not c.signals or self.front_end is not None,
                    f"case {c.name!r}: signals: true needs the study's front_end block")
            require(not (c.signals and c.detections_csv), f"case {c.name!r}: give signals or detections_csv, not both")

    @property
    def scans(self) -> int:
        return int(math.floor(self.duration_s / self.dt_s + 1e-9))

    def with_checkpoints(self, checkpoints):
        raise ConfigError("an SMC-PHD study has no learned methods: --checkpoint does not apply")

    def label_spec(self, m: PHDMethodSpec) -> LabelSpec:
        """The study's labelling settings with the method's options (checked like the YAML)."""
        base = to_dict(self.labelling)
        game_keys = set(to_dict(GameSpec()))
        opts = dict(m.options)
        own = {"gate_probability", "max_missed", "confirm_m", "confirm_n"}
        unknown = sorted(set(opts) - game_keys - own)
        if unknown:
            raise ConfigError(f"method {m.name!r}: unknown option(s) {unknown} (known: {', '.join(sorted(own))}, "
                              f"{', '.join(sorted(game_keys))})")
        base["game"] = {**base["game"], **{k: v for k, v in opts.items() if k in game_keys}}
        base.update({k: v for k, v in opts.items() if k not in game_keys})
        return from_dict(LabelSpec, {"method": m.labelling, **base}, where=f"methods.{m.name}")

    def case_settings(self, c: PHDCaseSpec) -> tuple[float, ClutterSpec, BistaticNoiseSpec]:
        pd = self.pd if c.pd is None else c.pd
        clutter = self.clutter if c.clutter_per_scan is None else dataclasses.replace(self.clutter,
                                                                                      per_scan=c.clutter_per_scan)
        return pd, clutter, c.noise or self.noise

    def to_dict(self) -> dict:
        return to_dict(self)


def is_phd(data) -> bool:
    return isinstance(data, dict) and data.get("kind") == "phd"


def phd_from_dict(data: dict, base_dir: str | Path = ".", where: str = "scenario") -> PHDScenario:
    sc = from_dict(PHDScenario, data, where=where)
    object.__setattr__(sc, "base_dir", str(Path(base_dir).resolve()))
    return sc


@dataclass
class PHDSetup:
    """A study resolved and checked: the measurement model of each case (range and range-rate; for
    a case from signals, range and Doppler), the flights (``x (K, N, 6)`` Cartesian, ``z (K, N, 2)``
    bistatic, ``alive (K, N)``), each method's labelling settings, the detections read from files."""

    scenario: PHDScenario
    models: dict[str, MeasurementModel]
    x: torch.Tensor
    z: torch.Tensor
    alive: torch.Tensor
    labels: dict[str, LabelSpec]
    recorded: dict[str, tuple[torch.Tensor, torch.Tensor]] = field(default_factory=dict)


def known_association_kf(z: torch.Tensor, origin: torch.Tensor, N: int, F: torch.Tensor, Q: torch.Tensor,
                         R: torch.Tensor, alive: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The reference of what association can reach: per run and aircraft, the exact Kalman filter
    (the PHD's CV model, ``H = I``) on exactly the detections that aircraft caused (``origin``),
    started at its first detection (births known). ``z (B, K, J, 2)``, ``origin (B, K, J)``;
    returns ``x (B, K, N, 2)``, ``P (B, K, N, 2, 2)`` and ``exists (B, K, N)`` (alive and started)."""
    B, K, J, _ = z.shape
    own = torch.full((B, K, N, 2), float("nan"), dtype=torch.float64)
    b, k, j = torch.nonzero(origin >= 0, as_tuple=True)
    own[b, k, origin[b, k, j]] = z[b, k, j].to(torch.float64)
    x = torch.zeros(B, N, 2, dtype=torch.float64)
    P = R.expand(B, N, 2, 2).clone()
    started = torch.zeros(B, N, dtype=torch.bool)
    xs, Ps, ex = [], [], []
    eye = torch.eye(2, dtype=torch.float64)
    for k in range(K):
        x, P = x @ F.T, F @ P @ F.T + Q
        zk = own[:, k]
        seen = torch.isfinite(zk).all(-1)
        Kg = P @ torch.linalg.inv(P + R)
        xu = x + (Kg @ (torch.nan_to_num(zk) - x)[..., None])[..., 0]
        Pu = (eye - Kg) @ P
        first = seen & ~started  # the first detection starts the filter
        x = torch.where(first[..., None], torch.nan_to_num(zk), torch.where(seen[..., None], xu, x))
        P = torch.where(first[..., None, None], R, torch.where(seen[..., None, None], Pu, P))
        started = (started | seen) & alive[k]
        xs.append(x)
        Ps.append(P)
        ex.append(started.clone())
    return torch.stack(xs, 1), torch.stack(Ps, 1), torch.stack(ex, 1)


def case_detections(setup: PHDSetup, c: PHDCaseSpec, b: int, g: torch.Generator):
    """``(z (b, K, J, 2), valid (b, K, J), origin (b, K, J) or None, front-end record or None)`` of a
    block of ``b`` runs: read from the case's file, simulated from the model (with each detection's
    origin), or measured by the signal chain."""
    sc = setup.scenario
    if c.name in setup.recorded:
        z, valid = (v.expand(b, *v.shape) for v in setup.recorded[c.name])
        return z, valid, None, None
    x = setup.x.expand(b, *setup.x.shape)
    model = setup.models[c.name]
    if c.signals:
        from ..frontend.chain import front_end_scans

        scans, record = front_end_scans(x, setup.alive, model, sc.front_end, g, progress=False)
        z = scans.z[:, :, 0].clone()
        z[..., 1] = -z[..., 1] * SPEED_OF_LIGHT / sc.geometry.transmitters[0].carrier_hz  # Doppler (Hz) -> m/s
        return z, scans.valid[:, :, 0], None, record
    pd, clutter, _ = sc.case_settings(c)
    scans = simulate_scans(x, model, pd, clutter, g, setup.alive)
    return scans.z[:, :, 0], scans.valid[:, :, 0], scans.origin[:, :, 0], None


def prepare_phd(sc: PHDScenario) -> PHDSetup:
    """Every user error surfaces here, before anything is written: flights never seen or passing
    over a sensor, unknown labelling options."""
    geometry = sc.geometry.build(3)
    fc = sc.geometry.transmitters[0].carrier_hz
    models = {}
    for c in sc.cases:
        noise = sc.case_settings(c)[2]
        if c.signals:  # the chain reports Doppler; the filter reads it as range-rate
            models[c.name] = MeasurementModel(geometry, ("range", "doppler"), (noise.range_m, noise.range_rate_mps * fc /
                                                                               SPEED_OF_LIGHT), (0, 2, 4), (1, 3, 5), "pair")
        else:
            models[c.name] = MeasurementModel(geometry, ("range", "range_rate"), (noise.range_m, noise.range_rate_mps),
                                              (0, 2, 4), (1, 3, 5), layout="pair")
    model = MeasurementModel(geometry, ("range", "range_rate"), (sc.noise.range_m, sc.noise.range_rate_mps),
                             (0, 2, 4), (1, 3, 5), layout="pair")
    x, alive = fly_all(sc.aircraft, sc.scans, sc.dt_s, model, sc.min_altitude_m, sc.max_range_m)
    z = torch.where(alive[..., None], model.h(torch.nan_to_num(x)), torch.full((), float("nan"), dtype=torch.float64))
    labels = {m.name: sc.label_spec(m) for m in sc.methods}
    sc.keyed_reference()  # a bad reference entry fails now, not after the run
    recorded = {c.name: read_detections_csv(sc.path(c.detections_csv), sc.scans) for c in sc.cases if c.detections_csv}
    return PHDSetup(sc, models, x, z, alive, labels, recorded)


def kappa_of(clutter: ClutterSpec) -> float:
    """Clutter intensity per scan and unit of bistatic range x range-rate (1 / (m m/s)); a tracker
    needs a positive one even where none is simulated (1e-3 points per scan)."""
    return max(clutter.per_scan, 1e-3) / clutter.volume_of(("range", "range_rate"))


def set_sums(x: torch.Tensor, exists: torch.Tensor, z: torch.Tensor, alive: torch.Tensor, c: float, p: float,
             labelled: bool) -> dict[str, np.ndarray]:
    """Sums over the runs of estimates ``x (B, K, M, 2)`` / ``exists (B, K, M)`` against the truth
    ``z (K, N, 2)`` / ``alive (K, N)`` (module docstring); ``labelled``: also switches and fragmentations."""
    B, K, M, _ = x.shape
    N = z.shape[1]
    t = torch.nan_to_num(z).expand(B, K, N, 2)
    t_mask = alive.expand(B, K, N)
    sc = set_scores(torch.nan_to_num(x[..., :1]), exists, t[..., :1], t_mask, c, p)
    a = sc.assignment  # (B, K, M): target of each estimate slot
    matched = a >= 0
    tz = t.gather(2, a.clamp(min=0)[..., None].expand(B, K, M, 2))
    err = torch.where(matched[..., None], torch.nan_to_num(x) - tz, torch.zeros((), dtype=x.dtype))
    out = {"ospa": sc.ospa.sum(0).numpy(), "gospa_loc": sc.gospa.localisation.sum(0).numpy(),
           "gospa_missed": sc.gospa.missed.sum(0).numpy(), "gospa_false": sc.gospa.false.sum(0).numpy(),
           "n_est": exists.sum(-1).to(torch.float64).sum(0).numpy(),
           "abs_card": (exists.sum(-1) - t_mask.sum(-1)).abs().to(torch.float64).sum(0).numpy(),
           "err_r2": (err[..., 0] ** 2).sum((0, 2)).numpy(), "err_v2": (err[..., 1] ** 2).sum((0, 2)).numpy(),
           "matched": matched.sum((0, 2)).to(torch.float64).numpy()}
    if labelled:
        out["switches"] = label_switches(a, t_mask).to(torch.float64).sum(0).numpy()
        out["fragmentations"] = fragmentations(a, t_mask).to(torch.float64).sum(0).numpy()
        out["switch_runs"] = label_switches(a, t_mask).sum(1).to(torch.float64).numpy()  # per run (B,)
    return out


PER_RUN = ("switch_runs", "labels_runs")
"""Quantities kept per run (concatenated over blocks); the others are summed."""


def _add(per: dict, s: dict) -> None:
    for q, v in s.items():
        per[q] = np.concatenate([per[q], v]) if q in PER_RUN and q in per else per.get(q, 0.0) + v


def run_phd(setup: PHDSetup, progress: bool = True) -> tuple[dict, dict]:
    """The PHD and every labelling of every case on every block: ``(sums, examples)``;
    ``sums[case][method]`` per-scan / per-target sums and ``seconds``; ``examples[case]`` run 0's
    detections, PHD estimates and labelled tracks."""
    from tqdm.auto import tqdm

    sc = setup.scenario
    c_m, p = sc.set_metrics.c_m, sc.set_metrics.p
    sums: dict = {}
    examples: dict = {}
    bar = tqdm(total=len(sc.cases) * sc.n_blocks * sc.scans, disable=not progress, unit="scan", desc=sc.name,
               leave=False)
    front_end_sums: dict = {}
    with torch.no_grad():
        for ci, c in enumerate(sc.cases):
            pd, clutter, noise = sc.case_settings(c)
            sd = torch.tensor([noise.range_m, noise.range_rate_mps], dtype=torch.float64)
            phd = SMCPHD(sc.phd, sd, pd, kappa_of(clutter), sc.dt_s)
            for block in range(sc.n_blocks):
                b = len(sc.block_runs_range(block))
                g = seeded_generator(sc.seed, ci, block)
                z, valid, origin, record = case_detections(setup, c, b, g)
                if record is not None:
                    fe = front_end_sums.setdefault(c.name, {})
                    for q, v in record.sums.items():
                        fe[q] = fe.get(q, 0.0) + v
                bar.set_postfix_str(f"{c.name} block {block + 1}/{sc.n_blocks}", refresh=False)
                t0 = time.perf_counter()
                est = phd.run(z, valid, seeded_generator(sc.seed, ci, block, zlib.crc32(PHD.encode())),
                              progress=lambda k: bar.update())
                phd_s = time.perf_counter() - t0
                per = sums.setdefault(c.name, {}).setdefault(PHD, {"seconds": 0.0})
                _add(per, set_sums(est.x, est.exists, setup.z, setup.alive, c_m, p, labelled=False))
                _add(per, {"expected": est.expected.sum(0).numpy(), "particles": est.particles.to(torch.float64).sum(0).numpy()})
                per["seconds"] += phd_s
                ex = None
                if block == 0:
                    ex = examples.setdefault(c.name, {"z": z[0].numpy(), "valid": valid[0].numpy(), "tracks": {},
                                                      "phd": (est.x[0].numpy(), est.exists[0].numpy())})
                if origin is not None:
                    t0 = time.perf_counter()
                    kx, kP, kex = known_association_kf(z, origin, setup.alive.shape[1], phd.F, phd.Q,
                                                       torch.diag(sd**2), setup.alive)
                    per = sums[c.name].setdefault(KNOWN, {"seconds": 0.0})
                    _add(per, set_sums(kx, kex, setup.z, setup.alive, c_m, p, labelled=False))
                    per["seconds"] += time.perf_counter() - t0
                    if ex is not None:
                        ex["tracks"][KNOWN] = (kx[0].numpy(), kex[0].numpy())
                for m in sc.methods:
                    t0 = time.perf_counter()
                    lab = label_tracks(est.x, est.P, est.exists, phd.F, phd.Q, setup.labels[m.name],
                                       seeded_generator(sc.seed, ci, block, zlib.crc32(m.name.encode())))
                    seconds = time.perf_counter() - t0
                    per = sums[c.name].setdefault(m.name, {"seconds": 0.0, "phd_seconds": 0.0})
                    _add(per, set_sums(lab.x, lab.exists, setup.z, setup.alive, c_m, p, labelled=True))
                    _add(per, {"labels_runs": lab.extras["labels"].to(torch.float64).numpy()})
                    if "repaired" in lab.extras:
                        _add(per, {"repaired": float(lab.extras["repaired"].sum()),
                                   "game_rounds": lab.extras["game_rounds"].to(torch.float64).numpy()})
                    per["seconds"] += seconds
                    per["phd_seconds"] += phd_s
                    if ex is not None:
                        ex["tracks"][m.name] = (lab.x[0].numpy(), lab.exists[0].numpy())
    bar.close()
    for name, fe in front_end_sums.items():
        sums[name]["front_end"] = fe
    return sums, examples


def _mean(v, n):
    return float(np.asarray(v).sum() / n) if n else float("nan")


def finalise_phd(setup: PHDSetup, sums: dict) -> dict:
    sc = setup.scenario
    R = sc.mc_runs
    alive = setup.alive.numpy()
    true_card = alive.sum(1).astype(float)
    p = sc.set_metrics.p
    out = {}
    for c in sc.cases:
        pd, clutter, noise = sc.case_settings(c)
        rows = {}
        for name, s in sums[c.name].items():
            if name == "front_end":
                continue
            ospa = s["ospa"] / R
            matched = s["matched"].sum()
            row = {
                "ospa_m": ospa.tolist(), "ospa_mean_m": float(ospa.mean()),
                "gospa_mean_m": float(np.mean(((s["gospa_loc"] + s["gospa_missed"] + s["gospa_false"]) / R) ** (1 / p))),
                "gospa_parts_mean": {k: float(np.mean(s[f"gospa_{k}"] / R)) for k in ("loc", "missed", "false")},
                "cardinality": (s["n_est"] / R).tolist(), "mean_abs_cardinality_error": float(np.mean(s["abs_card"] / R)),
                "rms_range_m": float(np.sqrt(s["err_r2"].sum() / matched)) if matched else None,
                "rms_range_rate_mps": float(np.sqrt(s["err_v2"].sum() / matched)) if matched else None,
            }
            if name == PHD:
                row.update(kind="SMC-PHD estimates (unlabelled)", expected=(s["expected"] / R).tolist(),
                           particles_mean=float(np.mean(s["particles"] / R)), seconds_per_run=float(s["seconds"] / R))
            elif name == KNOWN:
                row.update(kind="reference: Kalman filter per aircraft on its own detections, births known",
                           seconds_per_run=float(s["seconds"] / R))
            else:
                spec = setup.labels[name]
                row.update(kind=f"SMC-PHD + {'GTDA' if spec.method == 'gtda' else 'Hungarian'}", labelling=to_dict(spec),
                           label_switches_per_target=(s["switches"] / R).tolist(),
                           fragmentations_per_target=(s["fragmentations"] / R).tolist(),
                           label_switches_per_run=_mean(s["switches"], R),
                           fragmentations_per_run=_mean(s["fragmentations"], R),
                           runs_without_switch=float(np.mean(s["switch_runs"] == 0)),
                           labels_per_run=float(np.mean(s["labels_runs"])),
                           labelling_seconds_per_run=float(s["seconds"] / R),
                           seconds_per_run=float((s["seconds"] + s["phd_seconds"]) / R))
                if "repaired" in s:
                    row.update(conflicts_repaired_per_run=float(s["repaired"] / R),
                               game_rounds_mean=float(np.mean(s["game_rounds"] / sc.n_blocks)))
            rows[name] = row
        source = str(sc.path(c.detections_csv)) if c.detections_csv else ("signals" if c.signals else "simulated")
        out[c.name] = {"title": c.title or c.name, "pd": pd, "clutter_per_scan": clutter.per_scan,
                       "noise": to_dict(noise), "detections": source,
                       "true_cardinality": true_card.tolist(), "methods": rows}
        if "front_end" in sums[c.name]:
            from ..frontend.chain import summarise

            out[c.name]["front_end"] = summarise(sums[c.name]["front_end"], sc.front_end)
    return out


DEFINITIONS = {
    "ospa_m": "per scan: OSPA (order set_metrics.p, cut-off set_metrics.c_m) between the estimates' bistatic ranges "
              "and the aircraft's, mean over runs",
    "gospa_mean_m": "GOSPA (alpha 2, same order and cut-off) per scan, mean over runs, averaged over scans",
    "mean_abs_cardinality_error": "|estimates - aircraft present| per scan, mean over runs and scans",
    "rms_range_m / rms_range_rate_mps": "root mean square error over the estimate-aircraft pairs the OSPA assignment "
                                        "matches (inside the cut-off)",
    "label_switches_per_target": "per aircraft: how often the label matched to it changes between consecutive scans "
                                 "at which it is matched, mean over runs",
    "fragmentations_per_target": "per aircraft: how often its matched coverage is interrupted and resumed later "
                                 "(CLEAR MOT fragmentation), mean over runs",
    "labels_per_run": "labels (tracks) started in a run; the ideal is the number of aircraft",
    KNOWN: "the floor of what association can reach with the same motion model: an exact Kalman filter per aircraft "
           "on exactly its own detections, started at its first detection (simulated detections only; the seed's "
           "S-MSJPDA reference does not apply: one pair's range and range-rate do not fix the Cartesian state it "
           "tracks)",
    "expected": "per scan: the PHD's integral (sum of the particle weights) after the update, mean over runs",
    "seconds_per_run": "wall-clock seconds per Monte Carlo run on this machine: the PHD filter, plus the labelling "
                       "for the labelled rows",
}


def write_phd_outputs(setup: PHDSetup, sums: dict, examples: dict, out: Path, device: str) -> dict:
    from .phd_report import write_phd_report

    sc = setup.scenario
    res = {"scenario": sc.name, "kind": "phd", "seed": sc.seed, "mc_runs": sc.mc_runs, "environment": environment(device),
           "description": sc.description,
           "settings": {"scans": sc.scans, "dt_s": sc.dt_s, "pd": sc.pd, "phd": to_dict(sc.phd), "noise": to_dict(sc.noise),
                        "clutter": to_dict(sc.clutter), "clutter_intensity_per_m_mps": kappa_of(sc.clutter),
                        "min_altitude_m": sc.min_altitude_m, "max_range_m": sc.max_range_m,
                        "geometry": to_dict(sc.geometry), "aircraft": [a.name for a in sc.aircraft],
                        "methods": {m.name: to_dict(setup.labels[m.name]) for m in sc.methods},
                        "set_metrics": to_dict(sc.set_metrics), "block_runs": sc.block_runs},
           "definitions": DEFINITIONS, "reference": sc.keyed_reference(), "cases": finalise_phd(setup, sums)}
    (out / "results.json").write_text(json.dumps(res, indent=1, allow_nan=True) + "\n")
    write_phd_report(res, setup, examples, out)
    return res
