"""A scenario's methods (schema): each a :class:`MethodSpec` naming a registered kind, and the
grid search behind options set to ``tuned`` (:class:`TuningSpec`, run by :mod:`.tuning`).

Takes plain YAML data (through :func:`~pmsr_nn.config.from_dict`); gives frozen, checked specs.
Every option is checked against its kind's :class:`~pmsr_nn.methods.Option` (type, range,
choices); a bad one is refused in one line naming the method and the option.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ...config import require
from ...errors import ConfigError
from ...methods import method_kind

TUNABLE = ("q", "q_quiet", "q_manoeuvre", "stay")
"""Options that may be ``tuned`` (chosen from ``tuning.<option>_grid``), in grid order; each is
marked ``tunable`` in its method kind (:mod:`pmsr_nn.methods`)."""

TUNABLE_RANGES: dict[str, tuple[float, float]] = {"q": (0.0, 1.0e6), "q_quiet": (0.0, 1.0e6),
                                                  "q_manoeuvre": (0.0, 1.0e6), "stay": (0.0, 1.0)}
"""Inclusive range of every grid of :class:`TuningSpec`."""

MAX_TUNING_TRACKS = 500
"""Most tuning tracks (one filter call holds all of them: 500 IMM runs of 1000 steps take ~0.2 GB)."""

MAX_TUNING_POINTS = 1000
"""Most grid points one method's search may have (the product of its tuned options' grids)."""


def _check_option(method: str, key: str, value, opt) -> None:
    """``value`` of option ``key`` of ``method`` against its :class:`~pmsr_nn.methods.Option`
    ``opt`` (null, ``tuned``, a choice or a number in range), or a one-line error."""
    if value is None and opt.nullable:
        return
    if value == "tuned" and opt.tunable:
        return
    if opt.choices:
        if value not in opt.choices:
            raise ConfigError(f"method {method!r}: option {key} must be one of {', '.join(opt.choices)}, "
                              f"got {value!r:.40}")
        return
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not number or (opt.kind is int and not isinstance(value, int)) or not (opt.lo <= value <= opt.hi):
        extra = " or 'tuned'" if opt.tunable else ""
        raise ConfigError(f"method {method!r}: option {key} must be {'an integer' if opt.kind is int else 'a number'} "
                          f"in [{opt.lo}, {opt.hi}]{extra}, got {value!r:.40}")


@dataclass(frozen=True)
class MethodSpec:
    """A method to run: ``kind`` names a registered method kind (:mod:`pmsr_nn.methods`: its product,
    options and defaults), ``options`` its settings, ``checkpoint`` the trained tracker of a kind
    that needs one (``learned``)."""

    name: str
    kind: str
    checkpoint: str | None = None
    options: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        require(bool(self.name) and "/" not in self.name, f"method name {self.name!r} must be non-empty, without '/'")
        kind = method_kind(self.kind)
        if kind.needs_checkpoint:
            require(self.checkpoint is not None, f"method {self.name!r}: a {self.kind} method needs a checkpoint")
        else:
            require(self.checkpoint is None, f"method {self.name!r}: kind {self.kind} takes no checkpoint")
        unknown = sorted(set(self.options) - set(kind.options))
        require(not unknown, f"method {self.name!r}: unknown option(s) {unknown} for kind {self.kind!r} "
                             f"(valid: {sorted(kind.options) or 'none'})")
        for key, value in self.options.items():
            _check_option(self.name, key, value, kind.options[key])
        unread = [(k, kind.options[k].read_when) for k in self.options
                  if kind.options[k].read_when is not None
                  and not kind.options[k].read_when.holds(self.option(kind.options[k].read_when.key))]
        if unread:
            when = unread[0][1]
            keys = ", ".join(k for k, w in unread if w == when)
            now = self.option(when.key)
            raise ConfigError(f"method {self.name!r}: option(s) {keys} are read only with {when}, and this row has "
                              f"{when.key}: {'null' if now is None else now}: remove them (they would be recorded as "
                              "settings the row never used)")

    def option(self, key: str):
        return self.options.get(key, method_kind(self.kind).options[key].default)

    def tuned(self) -> list[str]:
        """Options set to ``tuned``, in :data:`TUNABLE` order."""
        return [k for k in TUNABLE if self.options.get(k) == "tuned"]


@dataclass(frozen=True)
class TuningSpec:
    """The grid search behind options set to ``tuned``: ``tracks`` truth tracks drawn from
    ``recipe`` (the training recipe, relative to the scenario file; null = the scenario's) with
    generator stream ``seed``, measured with the scenario's fixed noise (outliers included); each
    method runs once per point of the product of its tuned options' grids (``<option>_grid``),
    and the point with the lowest position RMSE after the warm-up is used."""

    tracks: int = 50
    seed: int = 12345
    recipe: str | None = None
    q_grid: tuple[float, ...] = ()
    q_quiet_grid: tuple[float, ...] = ()
    q_manoeuvre_grid: tuple[float, ...] = ()
    stay_grid: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        require(1 <= self.tracks <= MAX_TUNING_TRACKS, f"tuning.tracks must be in [1, {MAX_TUNING_TRACKS}], "
                                                       f"got {self.tracks}")
        require(self.seed >= 0, f"tuning.seed must be non-negative, got {self.seed}")
        for key in TUNABLE:
            grid = self.grid(key)
            lo, hi = TUNABLE_RANGES[key]
            for v in grid:
                require(lo <= v <= hi, f"tuning.{key}_grid: values must be in [{lo}, {hi}], got {v}")
            dup = sorted({v for v in grid if grid.count(v) > 1})
            require(not dup, f"tuning.{key}_grid holds {dup} more than once")

    def grid(self, key: str) -> tuple[float, ...]:
        return getattr(self, f"{key}_grid")
