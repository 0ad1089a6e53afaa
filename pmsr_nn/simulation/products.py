"""Sensor products of one truth: what each kind of tracker reads, made only when one asks.

A scenario's truth (:class:`Truth`: any number of targets, each alive over its own scans) is
seen through *products*, each a kind (:data:`pmsr_nn.product_kinds.PRODUCTS`) built by one
function from the truth and random generators:

* ``measurements`` (:class:`Streams`): every target's own clean measurement stream, association
  known, what the single-target filters, the learned trackers and the PCRB read;
* ``detections`` (:class:`Detections`): per sensor and scan, detections with missed targets and
  clutter, truth origin kept, what the multi-target trackers read; with ``illuminator_known``
  false (a single-frequency network) also the same detections pooled per receiver, the
  transmitter of each unknown to the trackers that read the pooled lists.

* ``rd_maps`` (:class:`~pmsr_nn.tbd.scene.RangeDopplerMaps`, made by :mod:`pmsr_nn.tbd.scene`):
  per transmitter and frame a range-Doppler map, what track-before-detect filters read.

The streams and the simulated detections are made here; detections from simulated signals
(:mod:`pmsr_nn.frontend.chain`) and the maps are made by the modules above, and
:mod:`pmsr_nn.product_kinds` lists every kind.
Every product carries the initiation prior of its readers: per target, the true state at its
birth scan plus a draw from ``N(0, P0)``. The prior is drawn from its own generator, so two
products built with equal initiation generators give their readers the same initial tracks.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..errors import ConfigError
from ..filters import Gaussian
from ..measurements import MeasurementModel, wrap_angle
from ..motion import KinematicModel
from ..rng import standard_normal
from .detections import ClutterSpec, PooledScans, Scans, pool_by_receiver, simulate_scans
from .tracks import apply_range_outliers, range_rows


@dataclass
class Truth:
    """True states ``x (B, K, N, n)`` (SI; NaN where a target is not alive) and ``alive (K, N)``
    (the same births and deaths in every run)."""

    x: torch.Tensor
    alive: torch.Tensor

    @property
    def births(self) -> torch.Tensor:
        """First scan of each target ``(N,)``."""
        return self.alive.to(torch.int64).argmax(0)

    def at_birth(self) -> torch.Tensor:
        """Each target's true state at its birth scan ``(B, N, n)``."""
        N = self.x.shape[2]
        return self.x[:, self.births, torch.arange(N)]


@dataclass(frozen=True)
class DesignedTruth:
    """Fixed flights ``x (K, N, n)`` (NaN outside ``alive (K, N)``): no random draw."""

    x: torch.Tensor
    alive: torch.Tensor

    def draw(self, b: int, g: torch.Generator) -> Truth:
        return Truth(self.x.expand(b, *self.x.shape), self.alive)


@dataclass(frozen=True)
class SampledTruth:
    """Flights from initial states ``x0 (N, n)`` with the process noise of ``motion`` (PSD ``q``),
    ``K`` scans of ``dt`` s, all targets alive throughout; one draw per run."""

    x0: torch.Tensor
    motion: KinematicModel
    K: int
    dt: float
    q: float

    @property
    def alive(self) -> torch.Tensor:
        return torch.ones(self.K, self.x0.shape[0], dtype=torch.bool)

    def draw(self, b: int, g: torch.Generator) -> Truth:
        N, n = self.x0.shape
        x = self.motion.sample(self.x0.expand(b, N, n).reshape(b * N, n), self.K, self.dt, self.q, g)
        return Truth(x.reshape(b, N, self.K, n).transpose(1, 2), self.alive)


@dataclass(frozen=True)
class SensorSetup:
    """How one case's truth is sensed.

    ``model``: the per-target stream's measurement model (its ``noise_std`` the deviations used);
    ``outlier_prob`` / ``outlier_scale``: heavy-tailed range errors of the stream
    (:func:`~.tracks.apply_range_outliers`); ``detection_model`` (pair layout), ``pd`` and
    ``clutter``: the detections, ``None`` where the scenario makes none (``clutter.per_scan`` is per
    list: per pair, or per receiver when ``illuminator_known`` is false); ``prior_sd (n,)``: the
    initiation prior's deviations.
    """

    model: MeasurementModel
    prior_sd: torch.Tensor
    outlier_prob: float = 0.0
    outlier_scale: float = 10.0
    detection_model: MeasurementModel | None = None
    pd: float | None = None
    clutter: ClutterSpec | None = None
    illuminator_known: bool = True
    front_end: object | None = None  # a frontend.chain.FrontEndSpec: detections from simulated signals
    rd_maps: object | None = None  # a tbd.scene.MapScene: range-Doppler maps for track-before-detect

    def to(self, device: torch.device | str) -> "SensorSetup":
        """The same sensing with its tensor (``prior_sd``) on ``device``."""
        import dataclasses

        return dataclasses.replace(self, prior_sd=self.prior_sd.to(device))

    def pair_clutter(self) -> ClutterSpec:
        """Clutter drawn per pair and scan: the scenario's per list, split evenly over a
        receiver's pairs when the detections are pooled per receiver (a Poisson rate splits
        exactly; a fixed count must divide)."""
        if self.illuminator_known:
            return self.clutter
        import dataclasses

        share = self.detection_model.n_pairs // len(self.detection_model.geometry.receivers)
        return dataclasses.replace(self.clutter, per_scan=self.clutter.per_scan / share)


def check_pooled_clutter(clutter: ClutterSpec, model: MeasurementModel, where: str) -> None:
    """One-line refusal of a fixed clutter count per receiver list (detections pooled per
    receiver) that does not split evenly over the receiver's pairs (:meth:`SensorSetup.pair_clutter`)."""
    share = model.n_pairs // len(model.geometry.receivers)
    if clutter.model == "fixed" and clutter.per_scan % share:
        raise ConfigError(f"{where}: {clutter.per_scan:g} fixed clutter points per receiver list do not split evenly over "
                          f"its {share} pairs (illuminator unknown); use a multiple of {share} or clutter model poisson")


def initiation_prior(truth: Truth, prior_sd: torch.Tensor, g: torch.Generator) -> Gaussian:
    """Per run and target: the state at birth plus a draw from ``N(0, diag(prior_sd^2))``,
    ``x (B, N, n)``, ``P (B, N, n, n)``."""
    start = truth.at_birth()
    B, N, n = start.shape
    x0 = start + standard_normal((B, N, n), g) * prior_sd
    return Gaussian(x0, torch.diag(prior_sd**2).expand(B, N, n, n).clone())


@dataclass
class Streams:
    """Each target's measurement stream ``z (B, N, K, m)`` (NaN outside its life) and the
    initiation prior ``x (B, N, n)`` at its birth scan."""

    z: torch.Tensor
    prior: Gaussian

    def to(self, device: torch.device | str) -> "Streams":
        """The same streams and prior on ``device``."""
        return Streams(self.z.to(device), self.prior.to(device))

    def first_scans(self, W: int) -> "Streams":
        """The streams of the first ``W`` scans (the prior as it is)."""
        return Streams(self.z[:, :, :W], self.prior)

    @classmethod
    def concat(cls, parts: list["Streams"]) -> "Streams":
        """The runs of ``parts`` one after another."""
        return cls(torch.cat([p.z for p in parts]), _concat_priors(parts))


def _concat_priors(parts) -> Gaussian:
    return Gaussian(torch.cat([p.prior.x for p in parts]), torch.cat([p.prior.P for p in parts]))


@dataclass
class Detections:
    """Detections of every sensor and scan (:class:`~.detections.Scans`) and the initiation prior
    of each target's track ``x (B, N, n)`` at its birth scan; ``pooled``: the same detections per
    receiver, illuminator unknown (only when the scenario's ``illuminator_known`` is false);
    ``front_end``: what the signal chain measured, when the detections came from signals
    (:class:`~pmsr_nn.frontend.chain.FrontEndRecord`)."""

    scans: Scans
    prior: Gaussian
    pooled: PooledScans | None = None
    front_end: object | None = None

    @classmethod
    def concat(cls, parts: list["Detections"]) -> "Detections":
        """The runs of ``parts`` one after another (lists padded: :meth:`~.detections.Scans.concat`);
        detections from signals are not joined (each block keeps its own front-end record)."""
        if any(p.front_end is not None for p in parts):
            raise ValueError("detections from signals carry one front-end record per block; they are not joined")
        pooled = None if parts[0].pooled is None else PooledScans.concat([p.pooled for p in parts])
        return cls(Scans.concat([p.scans for p in parts]), _concat_priors(parts), pooled)

    def to(self, device: torch.device | str) -> "Detections":
        """The same detections and prior on ``device`` (what the signal chain measured stays as it is)."""
        pooled = None if self.pooled is None else self.pooled.to(device)
        return Detections(self.scans.to(device), self.prior.to(device), pooled, self.front_end)

    def first_scans(self, W: int) -> "Detections":
        """The detections of the first ``W`` scans (the prior as it is; no front-end record)."""
        s = self.scans
        pooled = None
        if self.pooled is not None:
            p = self.pooled
            pooled = PooledScans(Scans(p.scans.z[:, :W], p.scans.valid[:, :W], p.scans.origin[:, :W]), p.pair[:, :W],
                                 p.routes)
        return Detections(Scans(s.z[:, :W], s.valid[:, :W], s.origin[:, :W]), self.prior, pooled)

    def runs(self, i: slice) -> "Detections":
        """The product of runs ``i``."""
        s = self.scans
        pooled = None
        if self.pooled is not None:
            p = self.pooled
            pooled = PooledScans(Scans(p.scans.z[i], p.scans.valid[i], p.scans.origin[i]), p.pair[i], p.routes)
        return Detections(Scans(s.z[i], s.valid[i], s.origin[i]), Gaussian(self.prior.x[i], self.prior.P[i]), pooled)


def make_streams(sensing: SensorSetup, truth: Truth, g: torch.Generator, g_prior: torch.Generator) -> Streams:
    """Noise (from ``g``), then the prior (``g_prior``), then range outliers (``g``, only when on)."""
    model = sensing.model
    B, K, N, _ = truth.x.shape
    clean = model.h(truth.x.transpose(1, 2))  # (B, N, K, m)
    z = clean + standard_normal((B, N, K, model.dim_z), g) * model.std_vector()
    z = torch.where(model.angle_mask, wrap_angle(z), z)
    prior = initiation_prior(truth, sensing.prior_sd, g_prior)
    z = apply_range_outliers(z, clean, range_rows(model), sensing.outlier_prob, sensing.outlier_scale, g)
    return Streams(z, prior)


def make_simulated_detections(sensing: SensorSetup, truth: Truth, g: torch.Generator,
                              g_prior: torch.Generator) -> Detections:
    """Detections drawn from the detection model (from ``g``: :func:`~.detections.simulate_scans`;
    pooled per receiver, from ``g`` again, when the illuminator is unknown), then the prior
    (``g_prior``). Detections from simulated signals are :mod:`pmsr_nn.product_kinds`' job."""
    scans = simulate_scans(truth.x, sensing.detection_model, sensing.pd, sensing.pair_clutter(), g, truth.alive)
    pooled = None if sensing.illuminator_known else pool_by_receiver(scans, sensing.detection_model, g)
    return Detections(scans, initiation_prior(truth, sensing.prior_sd, g_prior), pooled)
