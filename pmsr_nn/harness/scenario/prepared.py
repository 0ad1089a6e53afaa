"""A prepared scenario: what the preparation of a study gives and the runner's later stages read.

Takes nothing from the other stages; gives the types they share: :class:`Setup` (a scenario
resolved and checked, its methods loaded), its :class:`Case` list (a truth source with the
targets' births and deaths, how it is sensed, its :class:`Bounds`), the :class:`LossRule` of the
S-MSJPDA studies (also a scenario's ``loss`` section), the estimate space of each method
(:func:`method_space`), and the refusals the preparation (:mod:`.prepare_designed`) collects
before anything is written (:func:`method_refusals`, :func:`raise_refusals`).

Shapes: ``K`` scans, ``N`` targets; every curve is in metres (position) or metres per second
(velocity).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ...errors import ConfigError
from ...methods import MethodKind, Models, runs_on_any_device
from ...product_kinds import PRODUCTS
from ...simulation.products import DesignedTruth, SampledTruth, SensorSetup
from ...simulation.recipe import TrackRecipe
from .method_spec import MethodSpec


@dataclass
class Bounds:
    """PCRB curves of a case, each ``(K, N)`` numpy (NaN where a target is not alive):
    filtering and smoothing position / velocity RMSE bounds under the motion model's q, and the
    position bounds with q = 0 (the designed flights have no process noise)."""

    pos: np.ndarray
    vel: np.ndarray
    smoothing_pos: np.ndarray
    smoothing_vel: np.ndarray
    q0_pos: np.ndarray
    q0_smoothing_pos: np.ndarray


def set_scans_after(K: int, warmup: int) -> torch.Tensor:
    """``(K,)`` bool: the scans a case's set figures (OSPA, GOSPA, cardinality, the per-run GOSPA)
    average over in every scenario: every scan from ``warmup`` on, counted from the case's first
    scan. At those scans every living target counts, also one still inside its own warm-up (its
    start-up is part of the score), and so does a scan where no target lives (a track there is
    false). The point figures (RMSE, NEES) keep each target's own warm-up (``Case.scored``)."""
    return torch.arange(K) >= warmup


@dataclass
class Case:
    """A case ready to run. ``truth`` draws the true states of a block; ``alive (K, N)`` and
    ``scored (K, N)`` (alive and past the target's warm-up) say where each target counts;
    ``info`` is recorded beside the figures (the case's settings); ``bounds`` exist where every
    run flies the same flights, and, per causal learned method, ``memory_bounds``
    (``name -> (scans read, (K, N) curve)``) for designed scenarios only."""

    name: str
    title: str
    truth: DesignedTruth | SampledTruth
    sensing: SensorSetup
    alive: torch.Tensor
    scored: torch.Tensor
    targets: list[str]
    info: dict = field(default_factory=dict)
    bounds: Bounds | None = None
    memory_bounds: dict = field(default_factory=dict)
    methods: tuple[str, ...] = ()  # the methods the case runs (empty: every method of the scenario)
    set_scans: torch.Tensor = field(kw_only=True)  # (K,) bool: the scans set metrics average over (set_scans_after)

    def runs(self, spec) -> bool:
        """Whether the case runs method ``spec`` (a case may name the methods it runs)."""
        return not self.methods or spec.name in self.methods

    @property
    def set_scan_mask(self) -> torch.Tensor:
        """``(K,)`` the scans the set metrics (OSPA, GOSPA, cardinality) average over (:func:`set_scans_after`)."""
        return self.set_scans

    @property
    def steps(self) -> int:
        """Scans ``K`` of the case."""
        return self.alive.shape[0]

    @property
    def multi_target(self) -> bool:
        """Whether the case has more than one target."""
        return self.alive.shape[1] > 1


@dataclass
class LossRule:
    """The S-MSJPDA paper's track-loss rule (:func:`~pmsr_nn.metrics.track_loss`; a scenario's
    ``loss`` section): a track is lost after its dummy hypothesis was the most probable
    ``successive_scans`` scans in a row, or once its predicted bistatic-range deviation exceeds
    ``gate_range_sd_m`` (m)."""

    successive_scans: int = 4
    gate_range_sd_m: float = 5000.0


@dataclass
class Setup:
    """Everything a scenario run needs, resolved and checked before anything is written.

    ``scenario`` is the scenario as given (its ``to_dict`` names a shard's origin); ``methods``
    are its methods with tuned options resolved (``tuning``: the grid searches,
    :func:`~.tuning.tune`); ``kinds`` and ``resources`` their registered kinds and what each
    kind's ``load`` prepared (a learned method's tracker); ``settings`` and ``definitions`` go into
    ``results.json``; ``geometry`` draws the sensors in the figures.
    """

    scenario: object
    models: Models
    cases: list[Case]
    methods: tuple[MethodSpec, ...]
    kinds: dict[str, MethodKind]
    resources: dict
    causal: dict[str, bool]
    random_streams: str
    set_metric: tuple[float, float]
    settings: dict
    definitions: dict
    geometry: object
    loss: LossRule | None = None
    divergence_m: float | None = None
    tuning: dict = field(default_factory=dict)
    recipe: TrackRecipe | None = None
    prior_sd: torch.Tensor | None = None
    spaces: dict = field(default_factory=dict)  # (case, method) -> EstimateSpace or None (method_space)
    device: str = "cpu"  # where the methods run (pmsr evaluate --device); the draws and the scoring stay on the CPU

    @property
    def products(self) -> list[str]:
        """Product kinds the methods read, in registration order."""
        reads = {k.reads for k in self.kinds.values()}
        return [p for p in PRODUCTS if p in reads]


def method_space(setup: Setup, spec: MethodSpec, case: Case):
    """The :class:`~pmsr_nn.methods.EstimateSpace` a method's estimates live in (its kind's
    ``space``), or None: the scenario's state."""
    key = (case.name, spec.name)
    if key not in setup.spaces:
        kind = setup.kinds[spec.name]
        setup.spaces[key] = None if kind.space is None else kind.space(spec, case.sensing)
    return setup.spaces[key]


def method_refusals(methods, kinds: dict, resources: dict, alive: torch.Tensor, case: str,
                    sensing: SensorSetup) -> list[str]:
    """What each method's kind refuses of one case (its ``check`` and ``check_sensing``), one
    message per refusal."""
    out = []
    for spec in methods:
        kind = kinds[spec.name]
        for check, args in ((kind.check, (spec, alive, resources.get(spec.name), case)),
                            (kind.check_sensing, (spec, sensing))):
            if check is None:
                continue
            try:
                check(*args)
            except ConfigError as exc:
                out.append(str(exc))
    return out


def device_refusals(methods, kinds: dict, sensing: SensorSetup, device) -> list[str]:
    """Where the run's ``device`` is not the CPU: one message per method whose kind (or whose row
    of that kind, :func:`~pmsr_nn.methods.runs_on_any_device`) runs on the CPU only."""
    if torch.device(device).type == "cpu":
        return []
    return [f"method {spec.name!r}: kind {spec.kind} runs on the CPU only{runs_on_any_device(kinds[spec.name], spec, sensing)[1]}"
            f"; --device {device} is refused (use --device cpu)"
            for spec in methods if not runs_on_any_device(kinds[spec.name], spec, sensing)[0]]


def raise_refusals(refusals: list[str]) -> None:
    """Every refusal of a scenario file in one message (each said once, in order)."""
    if refusals:
        raise ConfigError("; ".join(dict.fromkeys(refusals)))
