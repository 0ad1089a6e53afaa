"""The track-generator recipe: every parameter of the CA multistatic dataset, with defaults.

The defaults are Section 2 of the MDFNN paper (Xu, Yi et al., FITEE 2023); the file
``datasets/fitee2023_ca.yaml`` spells every one of them out with its source, and a test keeps
the two identical. Where the paper is silent or inconsistent the choice is ours and documented
in that file.
"""

from __future__ import annotations

import re

import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Literal

from ..config import check_interval, from_dict, load_yaml, require, to_dict
from ..errors import ConfigError, GeometryError
from ..geometry import Geometry, Receiver, Transmitter, polar_position


@dataclass(frozen=True)
class TransmitterSpec:
    """A transmitter at ``position_m`` (m) with carrier ``carrier_hz``."""

    position_m: tuple[float, ...] = (0.0, 0.0)
    carrier_hz: float = 650.0e6


@dataclass(frozen=True)
class ReceiverSpec:
    """A receiver, either at ``position_m`` or at ``baseline_m`` along ``bearing_deg`` (clockwise
    from north) from the first transmitter."""

    position_m: tuple[float, ...] | None = None
    baseline_m: float | None = None
    bearing_deg: float | None = None

    def resolve(self, origin: tuple[float, ...]) -> tuple[float, ...]:
        has_polar = (self.baseline_m is not None, self.bearing_deg is not None)
        if self.position_m is not None:
            require(not any(has_polar), "a receiver needs either position_m, or baseline_m and bearing_deg, not both")
            return self.position_m
        require(all(has_polar), "a receiver needs either position_m, or both baseline_m and bearing_deg")
        require(self.baseline_m >= 0, f"baseline_m must be non-negative, got {self.baseline_m}")
        return polar_position(self.baseline_m, self.bearing_deg, origin)


def _default_receivers() -> tuple[ReceiverSpec, ...]:
    return (
        ReceiverSpec(baseline_m=7560.0, bearing_deg=240.0),
        ReceiverSpec(baseline_m=8120.0, bearing_deg=270.0),
        ReceiverSpec(baseline_m=8280.0, bearing_deg=300.0),
    )


@dataclass(frozen=True)
class GeometrySpec:
    transmitters: tuple[TransmitterSpec, ...] = (TransmitterSpec(),)
    receivers: tuple[ReceiverSpec, ...] = field(default_factory=_default_receivers)

    def build(self, dim: int) -> Geometry:
        """All transmitter-receiver pairs; 2-D sensor positions are on the ground (z = 0 when
        ``dim == 3``), a 3-D geometry may also give sensors their height ``[x, y, z]``."""
        require(len(self.transmitters) > 0 and len(self.receivers) > 0, "need at least one transmitter and one receiver")
        allowed = (2,) if dim == 2 else (2, 3)

        def placed(pos) -> tuple[float, ...]:
            require(len(pos) in allowed, f"sensor positions are [x, y]{' or [x, y, z]' if dim == 3 else ''} "
                                         f"coordinates, got {list(pos)}")
            return tuple(float(v) for v in pos) + (0.0,) * (dim - len(pos))

        origin = self.transmitters[0].position_m[:2]
        rx = [Receiver(placed(r.resolve(origin))) for r in self.receivers]
        tx = [Transmitter(placed(t.position_m), t.carrier_hz) for t in self.transmitters]
        try:
            return Geometry.all_pairs(tx, rx)
        except GeometryError as exc:
            raise ConfigError(str(exc)) from None


@dataclass(frozen=True)
class InitialStateSpec:
    """Polar decomposition of the initial state (Eqs. 7-9): uniform draws in each interval.

    Bearings and headings are clockwise from north, ``x = R sin(theta)``, ``y = R cos(theta)``.
    """

    range_m: tuple[float, float] = (2800.0, 8400.0)
    bearing_deg: tuple[float, float] = (0.0, 180.0)
    speed_mps: tuple[float, float] = (0.0, 26.0)
    heading_deg: tuple[float, float] = (-180.0, 180.0)
    accel_mps2: tuple[float, float] = (0.1, 5.0)
    accel_heading_deg: tuple[float, float] = (-180.0, 180.0)
    altitude_m: tuple[float, float] = (0.0, 0.0)

    def validate(self) -> None:
        check_interval("initial.range_m", self.range_m, nonneg=True)
        check_interval("initial.bearing_deg", self.bearing_deg)
        check_interval("initial.speed_mps", self.speed_mps, nonneg=True)
        check_interval("initial.heading_deg", self.heading_deg)
        check_interval("initial.accel_mps2", self.accel_mps2, nonneg=True)
        check_interval("initial.accel_heading_deg", self.accel_heading_deg)
        check_interval("initial.altitude_m", self.altitude_m, nonneg=True)


@dataclass(frozen=True)
class ManoeuvreSpec:
    """Drone manoeuvres on top of the CA track (``motion.manoeuvres``; absent = none).

    Between quiet stretches (uniform in ``quiet_s``) a track flies episodes: with probability
    ``turn_probability`` a coordinated turn (lateral acceleration uniform in ``turn_accel_mps2``,
    random side, for a duration uniform in ``turn_s``; capped at ``max_turn_rate_deg_s`` x speed),
    otherwise a speed change (along-track, uniform in ``speed_change_mps2``, random sign, for
    ``speed_change_s``; shortened so the commanded speed ends inside ``speed_mps``, skipped if it
    is already at that edge). Each episode's acceleration is ramped in and out over ``ramp_s``;
    ``substeps`` integration sub-steps per sampling interval. Units: s, m/s, m/s^2, deg/s.
    """

    quiet_s: tuple[float, float] = (30.0, 200.0)
    turn_probability: float = 0.5
    turn_accel_mps2: tuple[float, float] = (1.0, 4.0)
    turn_s: tuple[float, float] = (10.0, 60.0)
    max_turn_rate_deg_s: float = 20.0
    speed_change_mps2: tuple[float, float] = (0.5, 2.0)
    speed_change_s: tuple[float, float] = (5.0, 20.0)
    speed_mps: tuple[float, float] = (3.0, 24.0)
    ramp_s: float = 2.0
    substeps: int = 20

    def validate(self) -> None:
        w = "motion.manoeuvres"
        require(math.isfinite(self.ramp_s) and self.ramp_s > 0, f"{w}.ramp_s must be positive, got {self.ramp_s}")
        check_interval(f"{w}.quiet_s", self.quiet_s, positive=True)
        require(self.quiet_s[0] >= self.ramp_s, f"{w}.quiet_s must be at least ramp_s ({self.ramp_s} s) so episodes "
                                                f"do not overlap, got {list(self.quiet_s)}")
        require(0.0 <= self.turn_probability <= 1.0, f"{w}.turn_probability must be in [0, 1], got {self.turn_probability}")
        check_interval(f"{w}.turn_accel_mps2", self.turn_accel_mps2, nonneg=True)
        check_interval(f"{w}.turn_s", self.turn_s, nonneg=True)
        require(self.max_turn_rate_deg_s > 0, f"{w}.max_turn_rate_deg_s must be positive, got {self.max_turn_rate_deg_s}")
        check_interval(f"{w}.speed_change_mps2", self.speed_change_mps2, positive=True)
        check_interval(f"{w}.speed_change_s", self.speed_change_s, nonneg=True)
        check_interval(f"{w}.speed_mps", self.speed_mps, nonneg=True)
        require(1 <= self.substeps <= 1000, f"{w}.substeps must be in [1, 1000], got {self.substeps}")


MAX_EPISODES = 10_000
"""Most manoeuvre episodes a track may need (quiet stretches and episodes too short otherwise)."""


@dataclass(frozen=True)
class MotionSpec:
    """CA motion: interval ``dt_s``, ``steps`` samples per track, jerk PSD ``q_psd`` (m^2/s^5),
    optional drone ``manoeuvres`` flown on top of it (:class:`ManoeuvreSpec`)."""

    model: Literal["ca"] = "ca"
    dt_s: float = 1.0
    steps: int = 1000
    q_psd: float = 4.0
    q_psd_vertical: float = 0.0
    initial: InitialStateSpec = InitialStateSpec()
    manoeuvres: ManoeuvreSpec | None = None


@dataclass(frozen=True)
class NoiseSpec:
    """Per-track measurement noise deviations, each drawn uniformly from its interval; with
    probability ``range_outlier_prob`` (independently per range measurement, pair and scan) a
    range error's deviation is ``range_outlier_scale`` times the track's (heavy tails)."""

    range_m: tuple[float, float] = (16.0, 30.0)
    range_rate_mps: tuple[float, float] = (2.0, 4.0)
    azimuth_deg: tuple[float, float] = (0.6, 3.0)
    range_outlier_prob: float = 0.0
    range_outlier_scale: float = 10.0

    def intervals_si(self) -> list[tuple[float, float]]:
        """Intervals in SI units (m, m/s, rad), in measurement-component order."""
        deg = math.pi / 180
        return [self.range_m, self.range_rate_mps, (self.azimuth_deg[0] * deg, self.azimuth_deg[1] * deg)]

    def validate(self) -> None:
        for name, iv in (("range_m", self.range_m), ("range_rate_mps", self.range_rate_mps), ("azimuth_deg", self.azimuth_deg)):
            check_interval(f"noise.{name}", iv, positive=True)
        check_outliers("noise", self.range_outlier_prob, self.range_outlier_scale)


def check_outliers(where: str, prob: float, scale: float) -> None:
    """One-line errors for a range-outlier probability outside [0, 1] or a scale below 1."""
    require(0.0 <= prob <= 1.0, f"{where}.range_outlier_prob must be in [0, 1], got {prob}")
    require(scale >= 1.0, f"{where}.range_outlier_scale must be at least 1 (it multiplies the deviation), got {scale}")


@dataclass(frozen=True)
class EnvelopeSpec:
    """Table 1 of the paper: where a drone track is allowed to be.

    Distance and azimuth are measured from the transmitter (the paper's "passive radar", the
    origin of Eq. 7); the azimuth sector is clockwise from north, boresight 90 deg +- 60 deg.
    """

    range_m: tuple[float, float] = (200.0, 11000.0)
    speed_mps: tuple[float, float] = (0.0, 26.0)
    azimuth_deg: tuple[float, float] = (30.0, 150.0)

    def validate(self) -> None:
        check_interval("envelope.range_m", self.range_m, nonneg=True)
        check_interval("envelope.speed_mps", self.speed_mps, nonneg=True)
        check_interval("envelope.azimuth_deg", self.azimuth_deg)


@dataclass(frozen=True)
class EnvelopeVariantSpec:
    """Values that replace the paper's when ``variant: envelope``; tracks leaving are redrawn."""

    q_psd: float = 1.0e-7
    accel_mps2: tuple[float, float] = (0.0, 0.02)
    bearing_deg: tuple[float, float] = (30.0, 150.0)
    max_draws_per_track: int = 200

    def validate(self) -> None:
        require(self.q_psd >= 0, f"envelope_variant.q_psd must be non-negative, got {self.q_psd}")
        check_interval("envelope_variant.accel_mps2", self.accel_mps2, nonneg=True)
        check_interval("envelope_variant.bearing_deg", self.bearing_deg)
        require(self.max_draws_per_track >= 1, "envelope_variant.max_draws_per_track must be >= 1")


@dataclass(frozen=True)
class SplitSpec:
    """Fractions of whole tracks in each split. ``{train: 0, val: 0, test: 1}`` (:data:`NO_SPLITS`)
    is a dataset without splits: every track is a test track, for tracking and evaluation only."""

    train: float = 0.85
    val: float = 0.10
    test: float = 0.05

    @property
    def is_none(self) -> bool:
        """True for :data:`NO_SPLITS` (every track in 'test')."""
        return self.train == 0 and self.val == 0

    def validate(self) -> None:
        fr = (self.train, self.val, self.test)
        require(all(f >= 0 for f in fr), f"split fractions must be non-negative, got {fr}")
        require(abs(sum(fr) - 1.0) < 1e-9, f"split fractions must sum to 1, got {sum(fr)}")
        require(self.train > 0 or self.is_none, "the training split cannot be empty (a dataset without splits, "
                                                "for tracking only, is {train: 0, val: 0, test: 1})")

    def counts(self, n: int) -> tuple[int, int, int]:
        """Tracks per split: val and test rounded, train takes the rest."""
        n_val, n_test = round(n * self.val), round(n * self.test)
        n_train = n - n_val - n_test
        for name, frac, cnt in (("train", self.train, n_train), ("val", self.val, n_val), ("test", self.test, n_test)):
            if frac > 0 and cnt < 1:
                raise ConfigError(f"{n} tracks leave the {name} split empty; ask for more tracks")
        return n_train, n_val, n_test

    def fits(self, n: int) -> bool:
        """True when ``n`` tracks give every split with a positive fraction at least one track."""
        try:
            self.counts(n)
        except ConfigError:
            return False
        return True

    def min_tracks(self) -> int:
        """The fewest tracks that fill every split with a positive fraction (:meth:`fits`)."""
        n = 1
        for frac in (self.val, self.test):
            if frac > 0:
                n = max(n, int(0.5 / frac))  # round(n * frac) >= 1 needs n * frac >= 0.5 at least
        while not self.fits(n):
            n += 1
        return n


NO_SPLITS = SplitSpec(train=0.0, val=0.0, test=1.0)
"""Every track in the test split: a dataset for tracking and evaluation, not for training."""


@dataclass(frozen=True)
class StorageSpec:
    """How arrays are written: element type and tracks generated per chunk (bounds memory)."""

    dtype: Literal["float32", "float64"] = "float32"
    chunk_tracks: int = 256


@dataclass(frozen=True)
class TrackRecipe:
    """Everything that defines a generated dataset; see ``datasets/fitee2023_ca.yaml``."""

    name: str = "fitee2023_ca"
    seed: int = 0
    tracks: int = 70
    variant: Literal["envelope", "literal"] = "envelope"
    dim: Literal[2, 3] = 2
    window: int = 100
    min_sensor_distance_m: float = 50.0
    geometry: GeometrySpec = GeometrySpec()
    motion: MotionSpec = MotionSpec()
    noise: NoiseSpec = NoiseSpec()
    envelope: EnvelopeSpec = EnvelopeSpec()
    envelope_variant: EnvelopeVariantSpec = EnvelopeVariantSpec()
    splits: SplitSpec = SplitSpec()
    storage: StorageSpec = StorageSpec()

    def __post_init__(self) -> None:
        # The name becomes part of file names (the training cache): a plain name, never a path.
        require(re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}", self.name) is not None,
                f"name {self.name!r} must be a plain name of letters, digits, '.', '_' and '-' (it names files)")
        require(self.tracks >= 1, f"tracks must be at least 1, got {self.tracks}")
        require(self.seed >= 0, f"seed must be non-negative, got {self.seed}")
        m = self.motion
        require(m.dt_s > 0, f"motion.dt_s must be positive, got {m.dt_s}")
        require(m.steps >= 2, f"motion.steps must be at least 2, got {m.steps}")
        require(m.q_psd >= 0 and m.q_psd_vertical >= 0, "motion.q_psd and q_psd_vertical must be non-negative")
        require(self.window >= 1, f"window must be at least 1, got {self.window}")
        require(
            self.window <= m.steps,
            f"window of {self.window} samples is longer than the track ({m.steps} samples)",
        )
        require(self.min_sensor_distance_m >= 0, "min_sensor_distance_m must be non-negative")
        require(self.storage.chunk_tracks >= 1, "storage.chunk_tracks must be at least 1")
        m.initial.validate()
        if m.manoeuvres is not None:
            require(self.dim == 2, "motion.manoeuvres: manoeuvring tracks are planar; use dim 2")
            m.manoeuvres.validate()
            shortest = m.manoeuvres.quiet_s[0] + min(m.manoeuvres.turn_s[0], m.manoeuvres.speed_change_s[0])
            require((m.steps - 1) * m.dt_s / shortest < MAX_EPISODES,
                    f"motion.manoeuvres: quiet stretches and episodes as short as {shortest} s need more than "
                    f"{MAX_EPISODES} episodes per track; lengthen them")
        self.noise.validate()
        self.envelope.validate()
        self.envelope_variant.validate()
        self.splits.validate()
        self.splits.counts(self.tracks)
        self.geometry.build(self.dim)  # raises on a degenerate geometry

    # -- derived quantities -------------------------------------------------------------
    @property
    def windows_per_track(self) -> int:
        """Every full window: ``K - window + 1`` (Algorithm 1 literally stops one short, at ``K - window``)."""
        return self.motion.steps - self.window + 1

    def effective_motion(self) -> MotionSpec:
        """Motion parameters in force for this variant (envelope overrides applied)."""
        if self.variant == "literal":
            return self.motion
        ev = self.envelope_variant
        initial = replace(self.motion.initial, accel_mps2=ev.accel_mps2, bearing_deg=ev.bearing_deg)
        return replace(self.motion, q_psd=ev.q_psd, initial=initial)

    def initiation_prior_sd(self):
        """Deviations ``(dim_x,)`` of the prior the classical filters and the bounds start from:
        100 m, 5 m/s (a coarse first fix, as a track initiator gives) and the recipe's largest
        initial acceleration (m/s^2), per axis."""
        import torch

        accel = self.effective_motion().initial.accel_mps2[1]
        return torch.tensor([100.0, 5.0, max(accel, 0.01)] * self.dim, dtype=torch.float64)

    def with_overrides(self, **kw) -> "TrackRecipe":
        """A copy with top-level fields replaced (validated again)."""
        try:
            return replace(self, **{k: v for k, v in kw.items() if v is not None})
        except ConfigError as exc:
            raise ConfigError(f"recipe: {exc}") from None

    def to_dict(self) -> dict:
        """Plain data; options added after the first datasets (manoeuvres, range outliers) are
        left out while off, so a recipe without them keeps its manifest and training-cache key."""
        d = to_dict(self)
        if self.motion.manoeuvres is None:
            del d["motion"]["manoeuvres"]
        if self.noise.range_outlier_prob == 0.0 and self.noise.range_outlier_scale == 10.0:
            del d["noise"]["range_outlier_prob"], d["noise"]["range_outlier_scale"]
        return d


@contextmanager
def _naming_file(path):
    """Prefix the one-line ConfigError of a check of the recipe file ``path`` with the file's name
    (where the line does not name it already): ``r.yaml: recipe: need at least one ...``."""
    try:
        yield
    except ConfigError as exc:
        if str(path) in str(exc):
            raise
        raise ConfigError(f"{path}: {exc}") from None


def load_recipe(path) -> TrackRecipe:
    """Load and validate a recipe YAML file."""
    with _naming_file(path):
        return from_dict(TrackRecipe, load_yaml(path), where="recipe")


def load_recipe_for_simulation(path, *, tracks: int | None = None, seed: int | None = None,
                               variant: str | None = None, no_splits: bool = False) -> tuple[TrackRecipe, str | None]:
    """The recipe YAML at ``path`` with the command-line overrides (None: the recipe's own), as
    ``pmsr simulate`` writes it: with the recipe's train/val/test split, or with none
    (:data:`NO_SPLITS`, every track in 'test') when ``no_splits`` or when the tracks are too few
    to put one in every split the recipe asks for. Returns ``(recipe, note)``; ``note`` says why a
    recipe that asks for splits got none (None otherwise)."""
    with _naming_file(path):
        data = load_yaml(path)
        if not isinstance(data, dict):
            return from_dict(TrackRecipe, data, where="recipe"), None  # raises: a recipe is a mapping
        own = from_dict(SplitSpec, data["splits"], where="recipe.splits") if "splits" in data else SplitSpec()
        try:
            own.validate()
        except ConfigError as exc:
            raise ConfigError(f"recipe: {exc}") from None
        unsplit = from_dict(TrackRecipe, {**data, "splits": to_dict(NO_SPLITS)}, where="recipe")
    recipe = unsplit.with_overrides(tracks=tracks, seed=seed, variant=variant)
    if no_splits or own.is_none:
        return recipe, None
    if own.fits(recipe.tracks):
        return recipe.with_overrides(splits=own), None
    return recipe, (f"{recipe.tracks} track{'s are' if recipe.tracks > 1 else ' is'} too few for the recipe's "
                    f"train/val/test split {own.train:g}/{own.val:g}/{own.test:g}, which needs at least "
                    f"{own.min_tracks()}")


def recipe_from_dict(data: dict) -> TrackRecipe:
    return from_dict(TrackRecipe, data, where="recipe")
