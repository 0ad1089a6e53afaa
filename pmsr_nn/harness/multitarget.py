"""Multi-target scenarios (``kind: multitarget``): a formation of targets seen through missed
detections and clutter, every multi-target tracker on the same Monte Carlo draws.

This is the simulation study of Section IV of the S-MSJPDA paper: a few targets flying in parallel,
range + Doppler from every transmitter-receiver pair, trackers started at the truth plus noise.
Every draw of a block of runs (truth process noise, detections, clutter, the initiation offsets)
comes from a generator seeded by ``(seed, case, block)``; every method runs on whole blocks.

Cases vary the detection probability, the clutter count and the spacing of the formation
(:class:`MTCaseSpec`), which gives the paper's sweeps (Figs. 4-7, Tables 1-2) as one scenario each.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from .. import interrupts
from ..config import from_dict, require, to_dict
from ..errors import ConfigError
from ..filters import Gaussian
from ..measurements import MeasurementModel
from ..metrics import normalised_nees, squared_error, track_loss
from ..motion import ConstantVelocity
from ..rng import seeded_generator, standard_normal
from ..simulation.detections import ClutterSpec, simulate_scans
from ..simulation.recipe import GeometrySpec, ReceiverSpec, TransmitterSpec
from ..trackers.msjpda import JPDASettings, msjpda, true_assignment_ukf

MTMethodKind = Literal["s_msjpda", "p_msjpda", "true_assignment"]
ARCHITECTURE = {"s_msjpda": "sequential", "p_msjpda": "parallel"}


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
class MTNoiseSpec:
    range_m: float = 1000.0
    doppler_hz: float = 1.0

    def __post_init__(self) -> None:
        require(self.range_m > 0 and self.doppler_hz > 0, "noise deviations must be positive")


@dataclass(frozen=True)
class MTMotionSpec:
    """CV motion of truth and trackers: interval ``dt_s`` and acceleration variance ``q`` (m^2/s^4)."""

    dt_s: float = 1.0
    q: float = 1.0

    def __post_init__(self) -> None:
        require(self.dt_s > 0 and self.q >= 0, "motion: dt_s must be positive and q non-negative")


@dataclass(frozen=True)
class PriorSpec:
    """Track initiation: truth plus a draw from ``N(0, P0)``, ``P0`` from these deviations."""

    position_m: float = 500.0
    velocity_mps: float = 20.0

    def __post_init__(self) -> None:
        require(self.position_m > 0 and self.velocity_mps > 0, "prior deviations must be positive")

    def sd(self) -> torch.Tensor:
        return torch.tensor([self.position_m, self.velocity_mps] * 2, dtype=torch.float64)


@dataclass(frozen=True)
class LossSpec:
    """The paper's loss rule: dummy most probable ``successive_scans`` in a row, or the predicted
    bistatic-range deviation above ``gate_range_sd_m``."""

    successive_scans: int = 4
    gate_range_sd_m: float = 5000.0


@dataclass(frozen=True)
class MTMethodSpec:
    name: str
    kind: MTMethodKind
    m_best: int | None = None  # None: the scenario's tracker.m_best

    def __post_init__(self) -> None:
        require(bool(self.name) and "/" not in self.name, f"method name {self.name!r} must be non-empty, without '/'")


@dataclass(frozen=True)
class TrackerSpec:
    m_best: int = 10
    gate_probability: float = 0.999
    relaxation_iterations: int = 20


@dataclass(frozen=True)
class MTCaseSpec:
    """One setting: ``pd``, ``clutter_per_scan``, ``spacing_m`` and ``prior`` override the
    scenario's; ``reference_key`` is the key of this case in the paper's tables (default: none)."""

    name: str
    title: str = ""
    pd: float | None = None
    clutter_per_scan: float | None = None
    spacing_m: float | None = None
    prior: PriorSpec | None = None
    reference_key: str | None = None


@dataclass(frozen=True)
class MTReferenceSpec:
    """Paper run-time tables (method -> reference_key -> seconds per run) in ``file``."""

    timing: str
    file: str = "reference/paper_tables.json"
    label: str = "paper"


DEFAULT_GEOMETRY = GeometrySpec(
    transmitters=(TransmitterSpec((-38_000.0, 12_000.0), 93.1e6), TransmitterSpec((26_000.0, 31_000.0), 90.9e6),
                  TransmitterSpec((14_000.0, -42_000.0), 99.9e6)),
    receivers=(ReceiverSpec(position_m=(0.0, 0.0)),))
"""Three FM transmitters tens of km around one receiver (the paper's map is a sketch; see
evaluate/access2019_msjpda.yaml)."""


@dataclass(frozen=True)
class MultiTargetScenario:
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
    noise: MTNoiseSpec = MTNoiseSpec()
    motion: MTMotionSpec = MTMotionSpec()
    prior: PriorSpec = PriorSpec()
    pd: float = 0.8
    clutter: ClutterSpec = ClutterSpec()
    tracker: TrackerSpec = TrackerSpec()
    loss: LossSpec = LossSpec()
    converged_from_scan: int = 10
    sweep: Literal["none", "pd", "clutter_per_scan", "spacing_m"] = "none"
    reference: MTReferenceSpec | None = None
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

    @property
    def n_blocks(self) -> int:
        return math.ceil(self.mc_runs / self.block_runs)

    def block_size(self, block: int) -> int:
        return min(self.mc_runs, (block + 1) * self.block_runs) - block * self.block_runs

    def path(self, relative: str) -> Path:
        p = Path(relative).expanduser()
        return p if p.is_absolute() else Path(self.base_dir) / p

    def case_settings(self, case: MTCaseSpec) -> tuple[float, ClutterSpec, float]:
        """``(pd, clutter, spacing_m)`` of a case."""
        from dataclasses import replace

        pd = self.pd if case.pd is None else case.pd
        clutter = self.clutter if case.clutter_per_scan is None else replace(self.clutter, per_scan=case.clutter_per_scan)
        spacing = self.targets.spacing_m if case.spacing_m is None else case.spacing_m
        return pd, clutter, spacing

    def to_dict(self) -> dict:
        return to_dict(self)


def is_multitarget(data: dict) -> bool:
    return isinstance(data, dict) and data.get("kind") == "multitarget"


def multitarget_from_dict(data: dict, base_dir: str | Path = ".", where: str = "scenario") -> MultiTargetScenario:
    sc = from_dict(MultiTargetScenario, data, where=where)
    object.__setattr__(sc, "base_dir", str(Path(base_dir).resolve()))
    return sc


@dataclass
class MTSetup:
    scenario: MultiTargetScenario
    motion: ConstantVelocity
    model: MeasurementModel
    R: torch.Tensor


def prepare_multitarget(sc: MultiTargetScenario) -> MTSetup:
    geometry = sc.geometry.build(2)
    motion = ConstantVelocity(2)
    model = MeasurementModel(geometry, ("range", "doppler"), (sc.noise.range_m, sc.noise.doppler_hz), motion.pos_idx,
                             motion.vel_idx, layout="pair")
    for c in sc.cases:  # every target's whole flight must stay clear of the sensors
        _, _, spacing = sc.case_settings(c)
        t = torch.arange(sc.scans, dtype=torch.float64) * sc.motion.dt_s
        nominal = torch.einsum("kij,tj->tki", motion.F(t), sc.targets.initial_states(spacing))  # (T, K, 4), no noise
        if bool(model.near_sensor(nominal, 1000.0).any()):
            raise ConfigError(f"case {c.name!r}: a target passes within 1 km of a sensor")
    return MTSetup(sc, motion, model, model.R())


def draw_block(setup: MTSetup, case_index: int, block: int):
    """Truth ``(b, K, T, 4)``, detections and the initiation prior ``(b, T, 4)`` of one block."""
    sc = setup.scenario
    pd, clutter, spacing = sc.case_settings(sc.cases[case_index])
    g = seeded_generator(sc.seed, case_index, block)
    b, T = sc.block_size(block), sc.targets.count
    x0 = sc.targets.initial_states(spacing).expand(b, T, 4).reshape(b * T, 4)
    truth = setup.motion.sample(x0, sc.scans, sc.motion.dt_s, sc.motion.q, g).reshape(b, T, sc.scans, 4).transpose(1, 2)
    scans = simulate_scans(truth, setup.model, pd, clutter, g)
    sd = (sc.cases[case_index].prior or sc.prior).sd()
    prior = Gaussian(truth[:, 0] + standard_normal((b, T, 4), g) * sd, torch.diag(sd**2).expand(b, T, 4, 4).clone())
    return truth, scans, prior


def run_method(setup: MTSetup, spec: MTMethodSpec, scans, prior: Gaussian, case_index: int):
    sc = setup.scenario
    pd, clutter, _ = sc.case_settings(sc.cases[case_index])
    if spec.kind == "true_assignment":
        return true_assignment_ukf(scans, prior, setup.motion, sc.motion.dt_s, sc.motion.q, setup.model, setup.R)
    # a tracker needs a positive clutter density even where none was simulated
    density = max(clutter.density, 1e-3 / clutter.volume)
    settings = JPDASettings(pd=pd, clutter_density=density, m_best=spec.m_best or sc.tracker.m_best,
                            gate_probability=sc.tracker.gate_probability,
                            relaxation_iterations=sc.tracker.relaxation_iterations)
    return msjpda(scans, prior, setup.motion, sc.motion.dt_s, sc.motion.q, setup.model, setup.R, settings,
                  ARCHITECTURE[spec.kind])


def _swapped(x: torch.Tensor, truth: torch.Tensor, pos: list[int]) -> torch.Tensor:
    """``(B, T)``: at the last scan, track ``t`` is nearer another target's truth than its own."""
    est = x[:, -1][..., pos]
    tru = truth[:, -1][..., pos]
    dist = torch.cdist(est, tru)  # (B, T, T)
    return dist.argmin(-1) != torch.arange(x.shape[2])


def run_multitarget(setup: MTSetup, progress: bool = True) -> dict:
    """Every method on every case and block; the raw per-case sums."""
    from tqdm.auto import tqdm

    sc = setup.scenario
    pos = list(setup.motion.pos_idx)
    raw = {}
    bar = tqdm(total=len(sc.cases) * sc.n_blocks * len(sc.methods), disable=not progress, unit="method-block",
               desc=sc.name, leave=False)
    torch.set_grad_enabled(False)
    for ci, case in enumerate(sc.cases):
        acc = {m.name: {"pos": 0.0, "vel": 0.0, "nees": 0.0, "lost": 0, "swap": 0, "seconds": 0.0, "gap": 0.0}
               for m in sc.methods}
        example = {}
        for block in range(sc.n_blocks):
            interrupts.check()
            truth, scans, prior = draw_block(setup, ci, block)
            if ci == 0 and block == 0:  # untimed warm-up: one-off start-up costs stay out of the timing
                one = Gaussian(prior.x[:1], prior.P[:1])
                first = type(scans)(scans.z[:1], scans.valid[:1], scans.origin[:1])
                for spec in sc.methods:
                    run_method(setup, spec, first, one, ci)
            for spec in sc.methods:
                bar.set_postfix_str(f"{case.name} {spec.name}", refresh=False)
                t0 = time.perf_counter()
                res = run_method(setup, spec, scans, prior, ci)
                a = acc[spec.name]
                a["seconds"] += time.perf_counter() - t0
                a["pos"] = a["pos"] + squared_error(res.x, truth, pos).sum(0).numpy()  # (K, T)
                a["vel"] = a["vel"] + squared_error(res.x, truth, setup.motion.vel_idx).sum(0).numpy()
                a["nees"] = a["nees"] + normalised_nees(res.x, res.P, truth).sum(0).numpy()
                lost = track_loss(res.dummy_most_probable, res.gate_range_sd_m, sc.loss.successive_scans,
                                  sc.loss.gate_range_sd_m)
                a["lost"] += int((lost >= 0).sum())
                a["swap"] += int(_swapped(res.x, truth, pos).sum())
                a["gap"] = max(a["gap"], res.max_duality_gap)
                if block == 0:
                    example[spec.name] = res.x[0][..., pos].numpy()
                bar.update()
            if block == 0:
                example["truth"] = truth[0][..., pos].numpy()
        raw[case.name] = {"acc": acc, "example": example}
    bar.close()
    return raw


MT_DEFINITIONS = {
    "rmse_pos_m": "Eq. 22 of the S-MSJPDA paper per target and scan (root of the mean over runs of the squared "
                  "position error), averaged over targets and over scans converged_from_scan..K-1",
    "rmse_pos_all_scans_m": "the paper's position accuracy: the same, averaged over all scans",
    "loss_probability": "fraction of (run, target) tracks declared lost by the paper's rule (dummy most probable at "
                        "every sensor for successive_scans scans in a row, or predicted bistatic-range deviation "
                        "above gate_range_sd_m); a lost track keeps being tracked and stays in the RMSE",
    "swap_probability": "fraction of (run, target) tracks nearer another target's truth than their own at the last scan",
    "anees": "mean over runs, targets and scans >= converged_from_scan of the NEES / 4",
    "seconds_per_run": "wall-clock seconds per Monte Carlo run (a block of runs is processed at once and timed as a "
                       "whole, divided by its runs); all targets, all scans",
    "max_duality_gap": "largest duality gap (event cost minus Lagrangian lower bound, in nats: the event found is at least "
                       "exp(-gap) times as probable as the best) of the (N+1)-D assignments of P-MSJPDA",
}


def finalise_multitarget(setup: MTSetup, raw: dict) -> dict:
    sc = setup.scenario
    R, k0, T = sc.mc_runs, sc.converged_from_scan, sc.targets.count
    cases = {}
    for c in sc.cases:
        pd, clutter, spacing = sc.case_settings(c)
        methods, curves = {}, {}
        for spec in sc.methods:
            a = raw[c.name]["acc"][spec.name]
            rmse = np.sqrt(a["pos"] / R)  # (K, T)
            methods[spec.name] = {
                "kind": spec.kind,
                "rmse_pos_m": float(rmse[k0:].mean()), "rmse_vel_mps": float(np.sqrt(a["vel"] / R)[k0:].mean()),
                "anees": float((a["nees"] / R)[k0:].mean()), "seconds_per_run": a["seconds"] / R,
                "rmse_pos_all_scans_m": float(rmse.mean()),
                "rmse_pos_per_target_m": rmse[k0:].mean(0).tolist(),
                "loss_probability": a["lost"] / (R * T), "swap_probability": a["swap"] / (R * T),
                "max_duality_gap": a["gap"] if spec.kind == "p_msjpda" else None, "runs": R,
            }
            curves[spec.name] = rmse.T.tolist()  # per target: (K,)
        cases[c.name] = {"title": c.title or c.name, "pd": pd, "clutter_per_scan": clutter.per_scan,
                         "spacing_m": spacing, "prior": to_dict(c.prior or sc.prior), "reference_key": c.reference_key, "methods": methods,
                         "curves": {"rmse_pos_m_per_target": curves},
                         "pcrb": None}
    return cases


def describe_multitarget(setup: MTSetup) -> dict:
    sc = setup.scenario
    g = setup.model.geometry
    return {"dt_s": sc.motion.dt_s, "q": sc.motion.q, "scans": sc.scans, "targets": to_dict(sc.targets),
            "noise": to_dict(sc.noise), "clutter": to_dict(sc.clutter), "clutter_volume_m_hz": sc.clutter.volume,
            "prior": to_dict(sc.prior), "tracker": to_dict(sc.tracker), "loss": to_dict(sc.loss),
            "converged_from_scan": sc.converged_from_scan, "sweep": sc.sweep, "block_runs": sc.block_runs,
            "transmitters": [{"position_m": list(t.position_m), "carrier_hz": t.carrier_hz} for t in g.transmitters],
            "receivers": [list(r.position_m) for r in g.receivers],
            "methods": {m.name: {"kind": m.kind, "m_best": m.m_best or sc.tracker.m_best} for m in sc.methods}}
