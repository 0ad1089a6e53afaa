"""The config of a ``pmsr train`` run (``train/*.yaml``): data, model, optimiser and trainer
sections, read from YAML with ``KEY=VALUE`` overrides and validated in one line per error. The
run itself is :mod:`.training`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from ..config import from_dict, load_yaml, parse_yaml_value, require
from ..errors import ConfigError
from .config import ModelConfig
from .module import OptimConfig


@dataclass(frozen=True)
class DataConfig:
    """Where the windows come from.

    Either ``path``, an existing dataset directory, or a recipe (``recipe``: a YAML file; none:
    the built-in FITEE 2023 CA defaults) with optional overrides, simulated once into
    ``cache_dir`` under a name that hashes the resolved recipe (so a changed recipe never
    reuses stale data). ``window`` overrides the recipe's sequence size epsilon.
    ``eval_window_stride``: validation and test read every s-th window (all tracks, less time).
    """

    path: str | None = None
    recipe: str | None = None
    tracks: int | None = None
    steps: int | None = None
    seed: int | None = None
    variant: str | None = None
    window: int | None = None
    cache_dir: str = "data"
    batch_size: int = 256
    eval_window_stride: int = 10
    num_workers: int = 0
    fold: int | None = None
    folds: int | None = None

    def __post_init__(self) -> None:
        require(self.path is None or self.recipe is None, "data: give either path or recipe, not both")
        require(self.batch_size >= 1, f"data.batch_size must be positive, got {self.batch_size}")
        require(self.variant in (None, "envelope", "literal"), f"data.variant must be envelope or literal, got {self.variant!r}")
        require(self.window is None or self.window >= 1, f"data.window must be at least 1, got {self.window}")
        require(self.eval_window_stride >= 1, f"data.eval_window_stride must be at least 1, got {self.eval_window_stride}")
        require(self.num_workers >= 0, f"data.num_workers must be >= 0, got {self.num_workers}")
        require(self.tracks is None or self.tracks >= 1, f"data.tracks must be at least 1, got {self.tracks}")
        require(self.steps is None or self.steps >= 2, f"data.steps must be at least 2, got {self.steps}")
        require(self.seed is None or self.seed >= 0, f"data.seed must be non-negative, got {self.seed}")


@dataclass(frozen=True)
class TrainerConfig:
    """Lightning ``Trainer`` settings. ``train_batches_per_epoch`` caps an epoch (a fresh random
    subset of windows each epoch); none uses every window."""

    max_epochs: int = 50
    max_time_minutes: float | None = None
    train_batches_per_epoch: int | None = None
    val_batches: int | None = None
    accelerator: str = "auto"
    devices: int = 1
    strategy: str = "auto"
    num_nodes: int = 1
    precision: str = "32-true"
    deterministic: bool = True
    gradient_clip_val: float | None = 1.0
    early_stopping_patience: int | None = 10
    checkpoint_every_n_steps: int = 200
    log_every_n_steps: int = 20
    threads: int | None = None
    progress: bool = True

    def __post_init__(self) -> None:
        require(self.max_epochs >= 1, f"trainer.max_epochs must be positive, got {self.max_epochs}")
        require(self.devices >= 1 and self.num_nodes >= 1, "trainer.devices and trainer.num_nodes must be positive")
        require(self.checkpoint_every_n_steps >= 1, "trainer.checkpoint_every_n_steps must be positive")
        for name in ("train_batches_per_epoch", "val_batches", "threads", "early_stopping_patience"):
            v = getattr(self, name)
            require(v is None or v >= 1, f"trainer.{name} must be at least 1 (or null), got {v}")
        require(self.max_time_minutes is None or self.max_time_minutes > 0,
                f"trainer.max_time_minutes must be positive (or null), got {self.max_time_minutes}")
        require(self.gradient_clip_val is None or self.gradient_clip_val > 0,
                f"trainer.gradient_clip_val must be positive (or null), got {self.gradient_clip_val}")
        require(self.log_every_n_steps >= 1, f"trainer.log_every_n_steps must be positive, got {self.log_every_n_steps}")


@dataclass(frozen=True)
class TrainConfig:
    """A whole training run (``train/*.yaml``). ``model`` may name a file under ``models/``."""

    name: str = "tracker"
    seed: int = 0
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    trainer: TrainerConfig = field(default_factory=TrainerConfig)

    def __post_init__(self) -> None:
        require(0 <= self.seed < 2**32, f"seed must be in [0, 2^32), got {self.seed}")  # Lightning's range


# -- loading ---------------------------------------------------------------------------------

def _find(path: str, base: Path, what: str) -> Path:
    """``path`` as given (relative to the working directory), else relative to ``base``."""
    for p in (Path(path), base / path):
        if p.exists():
            return p
    raise ConfigError(f"{what} not found: {path} (looked in the working directory and {base})")


def apply_overrides(raw: dict, overrides: list[str]) -> dict:
    """``['trainer.max_epochs=5', 'model.hidden=[64,64]']`` applied to a nested dict (YAML values)."""
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"override {item!r} is not KEY=VALUE (e.g. trainer.max_epochs=5)")
        value = parse_yaml_value(text, where=f"override {key}")
        node = raw
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override {item!r}: {p} is not a section")
        node[parts[-1]] = value
    return raw


def load_train_config(path: str | Path | None, overrides: list[str] = ()) -> TrainConfig:
    """Read a training config, expand a ``model: FILE`` reference, apply overrides, validate."""
    raw = load_yaml(path) if path is not None else {}
    base = Path(path).parent if path is not None else Path(".")
    if isinstance(raw.get("model"), str):
        raw["model"] = load_yaml(_find(raw["model"], base, "model config"))
    raw = apply_overrides(raw, list(overrides))
    cfg = from_dict(TrainConfig, raw, where="train config")
    d = cfg.data
    if d.path is not None:
        d = replace(d, path=str(_find(d.path, base, "dataset")))
    if d.recipe is not None:
        d = replace(d, recipe=str(_find(d.recipe, base, "recipe")))
    return replace(cfg, data=d)


def resolve_recipe(data: DataConfig):
    """The recipe a data config describes (built-in defaults when it names none)."""
    from ..simulation.recipe import TrackRecipe, load_recipe

    recipe = load_recipe(data.recipe) if data.recipe else TrackRecipe()
    if data.steps is not None:
        recipe = recipe.with_overrides(motion=replace(recipe.motion, steps=data.steps))
    return recipe.with_overrides(tracks=data.tracks, seed=data.seed, variant=data.variant)
