"""The methods a scenario can run, behind one interface: a product in, labelled estimates out.

Every method kind is a :class:`MethodKind` in :data:`REGISTRY`: the product it reads
(:mod:`pmsr_nn.simulation.products`), its options with defaults and ranges, whether it needs a checkpoint,
``run(call) -> Estimates`` and the figures it reports beside the runner's (its ``metrics``,
:mod:`.kind_metrics`). The modules of this package register their kinds when imported, and :func:`registry`
imports every module of the package, so a new tracker is one module here (plus its tests): the runner and the
report need no edit. Another installed package registers its kinds through the entry-point group
:data:`PLUGIN_GROUP` (``pmsr_nn.methods``), loaded once when the registry is first consulted
(:func:`load_plugins`).

* :mod:`.single_target`: EKF, UKF, IMM, SI+KF, particle filter and learned trackers, each run
  on every target's own stream (association known);
* :mod:`.msjpda`: S-/P-MSJPDA and the true-assignment reference, on the detections;
* :mod:`.pmht`: PMHT, 3-D association PMHT and the true-assignment smoother, on the detections;
* :mod:`.phd`: the multi-sensor SMC-PHD with GTDA or Hungarian track labelling, on the detections;
* :mod:`.tbd`: track-before-detect (PMB, ICMB, modified ICMB) and detect-then-track, on range-Doppler maps;
* :mod:`.phd_pair`: the SMC-PHD in one pair's bistatic plane with GTDA or Hungarian labelling, and its
  known-association Kalman filter reference, on the detections (scored in that plane);
* :mod:`.bound`: the PCRB as a row (``kind: pcrb``), filled by the runner, never called;
* :mod:`.stonesoup`: Stone Soup's JPDA or GNN on the detections (optional extra; checked when a
  scenario uses it).
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
import types
import zlib
from dataclasses import dataclass, field
from typing import Any, Callable

import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..motion import KinematicModel
from ..simulation.products import SensorSetup
from ..trackers.base import Estimates


@dataclass
class Models:
    """What the classical methods share: motion and measurement models, interval ``dt`` (s),
    process-noise PSD ``q`` (the motion model's unit), measurement covariance ``R (m, m)`` and
    deviations ``noise_std (m_c,)`` per component of the per-target stream."""

    motion: KinematicModel
    model: MeasurementModel
    dt: float
    q: float
    R: torch.Tensor
    noise_std: torch.Tensor

    def to(self, device: torch.device | str) -> "Models":
        """The same models with their tensors (``R``, ``noise_std``) on ``device``."""
        return Models(self.motion, self.model, self.dt, self.q, self.R.to(device), self.noise_std.to(device))


@dataclass
class MethodCall:
    """One call of a method on a block of runs: its ``spec`` (``MethodSpec``, options resolved),
    the ``product`` it reads, the targets' lives ``alive (K, N)``, the shared ``models``, how
    the case is sensed (``sensing``), what :attr:`MethodKind.load` prepared (``resource``), and
    ``seed``: the block's random stream, for methods that draw."""

    spec: Any
    product: Any
    alive: torch.Tensor
    models: Models
    sensing: SensorSetup
    resource: Any = None
    seed: tuple[int, ...] = ()

    def to(self, device: torch.device | str) -> "MethodCall":
        """The same call with its product, the lives, the models and the sensing on ``device``
        (the product a ``.to(device)`` of its own, :mod:`pmsr_nn.simulation.products`); the
        ``resource`` was made on the run's device by the kind's ``load``."""
        return MethodCall(self.spec, self.product.to(device), self.alive.to(device), self.models.to(device),
                          self.sensing.to(device), self.resource, self.seed)


from ..trackers.jpda import MIN_CLUTTER_PER_SCAN  # noqa: E402,F401 - the kinds' clutter floor, re-exported


@dataclass(frozen=True)
class ReadWhen:
    """When an option is read at all: only while option ``key`` is one of ``values`` (``values``
    empty: while ``key`` is not null). A row that sets an option its other options leave unread is
    refused (:meth:`MethodSpec`), since results.json would record it as a setting of the row."""

    key: str
    values: tuple = ()

    def holds(self, value) -> bool:
        return value is not None if not self.values else value in self.values

    def __str__(self) -> str:
        return f"{self.key} not null" if not self.values else f"{self.key}: {' | '.join(map(str, self.values))}"


@dataclass(frozen=True)
class Option:
    """An option: ``default``, ``kind`` (int or float), inclusive range; ``nullable``: null means
    a default taken elsewhere; ``tunable``: may be ``tuned`` (a grid search picks it); ``choices``:
    a string option, one of these names (``kind`` str; the range does not apply); ``null``: what
    null means, for ``pmsr methods``; ``read_when``: the other option's setting without which this
    one is not read (:class:`ReadWhen`; None: always read)."""

    default: Any
    kind: type = float
    lo: float = 0.0
    hi: float = 1.0e6
    nullable: bool = False
    tunable: bool = False
    choices: tuple[str, ...] = ()
    null: str = ""
    read_when: ReadWhen | None = None

    def __post_init__(self) -> None:
        if self.choices and (self.kind is not str or self.tunable or self.default not in self.choices):
            raise ValueError(f"a choice option is a str, not tunable, its default one of {self.choices}")


@dataclass(frozen=True)
class MethodKind:
    """A registered method kind (see the module docstring).

    ``load(spec, context) -> resource`` runs before anything is written (it loads and checks a checkpoint);
    ``causal(resource)`` says whether an estimate at scan k reads only scans up to k; ``check(spec, alive, resource,
    case)`` refuses a case the method can not run and ``check_sensing(spec, sensing)`` one whose sensing (a
    :class:`SensorSetup`) it can not read (one-line errors); ``starts_tracks``: the kind always starts its own
    tracks from the detections (no ``initiation`` option to say so; the report scores its rows as tracks started
    from detections); ``bound``: the kind is an information bound, not an estimator (:mod:`.bound`): the runner
    calls nothing and fills its row from the case's bound; ``space(spec, sensing) -> EstimateSpace``: the kind's
    estimates are not the scenario's state but live in another space (one pair's bistatic plane): the runner scores
    them against the truth projected into it (:class:`EstimateSpace`); ``initiation``: how the kind's tracks start
    where the runner can not tell from ``reads`` and ``starts_tracks`` (e.g. ``association known`` for a reference
    that reads the detections' origins); ``pooled_lists``: where the scenario pools the detections per receiver (a
    single-frequency network), the kind reads those lists (the illuminator unknown); the other readers of
    ``detections`` read the per-pair lists (the illuminator given); ``metrics``: the kind's own figures beside the
    runner's (:class:`~.kind_metrics.Metric` objects; none by default); ``any_device``: the kind
    runs on the device of its inputs (``pmsr evaluate --device cuda``: every tensor it makes is
    made there, tests/test_device_agnostic.py), or ``(spec, sensing) -> (bool, why not)`` where that
    depends on the row (:func:`runs_on_any_device`); a kind or row without it runs on the CPU only and
    is refused, in one line, on any other device; ``batchable``: a run's estimates do not depend
    on the other runs of its call (nothing drawn from the block's stream, no per-call state), so the runner may call
    the kind on several blocks' runs at once (``--batch-runs``, :mod:`pmsr_nn.harness.run.batches`)."""

    name: str
    reads: str
    run: Callable[[MethodCall], Estimates]
    options: dict[str, Option] = field(default_factory=dict)
    needs_checkpoint: bool = False
    load: Callable | None = None
    causal: Callable[[Any], bool] = lambda resource: True
    check: Callable | None = None
    check_sensing: Callable | None = None
    description: str = ""
    starts_tracks: bool = False
    bound: bool = False
    space: Callable | None = None
    initiation: str = ""
    pooled_lists: bool = False
    metrics: tuple = ()
    any_device: bool | Callable = False
    batchable: bool = False


def runs_on_any_device(kind: MethodKind, spec, sensing: SensorSetup) -> tuple[bool, str]:
    """Whether a row (``spec``) of ``kind`` on a case's ``sensing`` runs on any device
    (``MethodKind.any_device``: a bool, or ``(spec, sensing) -> (bool, why not)`` where it depends
    on the row), and if not, why (``""`` or `` (reason)``). A bound is never called: any device."""
    if kind.bound:
        return True, ""
    if callable(kind.any_device):
        return kind.any_device(spec, sensing)
    return bool(kind.any_device), ""


def lists_read(kind: MethodKind) -> str:
    """Which detection lists a reader of ``detections`` takes where a single-frequency network
    pools them per receiver (``MethodKind.pooled_lists``)."""
    return "pooled per receiver, illuminator unknown" if kind.pooled_lists else "per pair, illuminator given"


@dataclass(frozen=True)
class EstimateSpace:
    """Where a kind's estimates live when they are not the scenario's state (``MethodKind.space``).

    ``project(x (..., n)) -> (..., m)`` maps true states (finite) to the estimates' columns,
    noise-free (a measurement model's ``h``); ``key`` names the space (rows with one key share one
    projected truth per block); ``pos`` / ``vel`` are the columns the runner scores as "position"
    (OSPA, GOSPA, position RMSE) and "velocity"; ``title``, ``pos_label`` and ``vel_label`` say in
    the report what those figures are (e.g. bistatic range in metres, one axis: not comparable with
    a Cartesian OSPA)."""

    key: str
    project: Callable
    title: str
    pos: tuple[int, ...] = (0,)
    vel: tuple[int, ...] = (1,)
    pos_label: str = "position (m)"
    vel_label: str = "velocity (m/s)"


REGISTRY: dict[str, MethodKind] = {}


@dataclass(frozen=True)
class Plugin:
    """Where a kind registered from another installed package came from: its ``entry_point``
    (``name = value`` in the group :data:`PLUGIN_GROUP`), the ``distribution`` that declares it
    (name and version) and the ``module`` the entry point names."""

    entry_point: str
    distribution: str
    module: str

    def __str__(self) -> str:
        return f"entry point '{self.entry_point}' of {self.distribution}"


class PluginError(ConfigError):
    """A method-kind plugin can not be loaded: it fails to import, registers a name another kind
    has, or registers nothing (one line naming its entry point and distribution)."""


PLUGIN_GROUP = "pmsr_nn.methods"
"""The entry-point group through which another installed package registers method kinds: each
entry point names a module that calls :func:`register` when imported, or a callable (``module:
function``) that does when called with no argument."""

PLUGINS: dict[str, Plugin] = {}
"""Kind name -> the :class:`Plugin` that registered it (kinds of this package are not here)."""

_loading: tuple[Plugin, set[str]] | None = None  # the plugin being loaded and the kinds there before it


def register(kind: MethodKind) -> MethodKind:
    """Add ``kind`` to :data:`REGISTRY`; a name registered twice is an error (naming the plugin
    whose module registers it, while one loads)."""
    if kind.name in REGISTRY:
        if _loading is not None:
            plugin, before = _loading
            owner = PLUGINS.get(kind.name)
            what = (f"the kind of {owner}" if owner is not None else "a built-in kind" if kind.name in before
                    else "registered twice by it")
            raise PluginError(f"method-kind plugin {plugin} registers method kind {kind.name!r}, which is {what}: "
                              "rename it")
        raise ValueError(f"method kind {kind.name!r} is registered twice")
    REGISTRY[kind.name] = kind
    return kind


_loaded = False
_plugins_loaded = False


def registry() -> dict[str, MethodKind]:
    """Every method kind: each module of this package imported once, then the kinds of other
    installed packages (:func:`load_plugins`)."""
    global _loaded
    if not _loaded:
        for info in pkgutil.iter_modules(__path__):
            importlib.import_module(f"{__name__}.{info.name}")
        _loaded = True
    load_plugins()
    return REGISTRY


def _distribution(ep) -> str:
    dist = getattr(ep, "dist", None)
    return "an unknown distribution" if dist is None else f"distribution {dist.metadata['Name']} {dist.version}"


def _load_one(plugin: Plugin, ep) -> None:
    """Import (or call) one entry point, its import errors as one :class:`PluginError` line."""
    global _loading
    _loading = (plugin, set(REGISTRY))
    try:
        loaded = ep.load()
        if callable(loaded) and not isinstance(loaded, types.ModuleType):
            loaded()
    except PluginError:
        raise
    except Exception as exc:
        first = (str(exc).strip().splitlines() or [""])[0][:200]
        raise PluginError(f"method-kind plugin {plugin} fails to load: {type(exc).__name__}"
                          + (f": {first}" if first else "")) from None
    finally:
        _loading = None


def load_plugins() -> None:
    """Register, once, the kinds of every entry point of :data:`PLUGIN_GROUP` (after the built-in
    kinds, in the entry points' order by name). A plugin that fails to import, registers a name
    another kind has, or registers nothing is a one-line :class:`PluginError`; the kinds of every
    plugin are then taken out again (their modules out of ``sys.modules``), and the next
    consultation tries again."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    from importlib.metadata import entry_points

    start, tried = set(REGISTRY), []
    try:
        for ep in sorted(entry_points(group=PLUGIN_GROUP), key=lambda e: (e.name, e.value)):
            plugin = Plugin(f"{ep.name} = {ep.value}", _distribution(ep), ep.module)
            before = set(REGISTRY)
            tried.append(ep.module)
            _load_one(plugin, ep)
            # a module imported before (e.g. by the user's script) registered its kinds then
            new = [n for n, k in REGISTRY.items() if n not in before or (n not in PLUGINS and _within(k, ep.module))]
            if not new:
                raise PluginError(f"method-kind plugin {plugin} registers no method kind (its module should call "
                                  "pmsr_nn.methods.register(MethodKind(...)) when imported)")
            PLUGINS.update({n: plugin for n in new})
    except PluginError:
        for n in set(REGISTRY) - start:
            del REGISTRY[n]
            PLUGINS.pop(n, None)
        for m in tried:  # imported again (registering again) when next consulted
            sys.modules.pop(m, None)
        raise
    _plugins_loaded = True


def _within(kind: MethodKind, module: str) -> bool:
    """``kind``'s ``run`` is defined in ``module`` or a module under it."""
    where = getattr(kind.run, "__module__", None) or ""
    return where == module or where.startswith(f"{module}.")


def forget_plugins() -> None:
    """Take the plugins' kinds out of the registry and their modules out of ``sys.modules``, so
    that the next consultation discovers the installed plugins afresh (tests install one)."""
    global _plugins_loaded
    modules = {p.module for p in PLUGINS.values()}
    for n in list(PLUGINS):
        REGISTRY.pop(n, None)
    PLUGINS.clear()
    for m in modules:
        sys.modules.pop(m, None)
    importlib.invalidate_caches()
    _plugins_loaded = False


def _foreign_kinds() -> dict[str, str]:
    """Kind name -> the module of its ``run``, for kinds registered by code outside pmsr_nn that
    is not an installed plugin (e.g. a user's script that calls :func:`register`)."""
    out = {}
    for name, kind in REGISTRY.items():
        module = getattr(kind.run, "__module__", None) or ""
        if name not in PLUGINS and module and module != __name__.split(".")[0] and \
                not module.startswith(__name__.split(".")[0] + "."):
            out[name] = module
    return out


def plugin_at_fault(exc: BaseException) -> str | None:
    """Where on ``exc``'s traceback code of a kind from outside pmsr_nn raised it: ``method kind
    'K' of module M (entry point ... of distribution ...)`` for a plugin, ``... (registered by
    that module, not by pmsr_nn)`` for a kind a user's own code registered (M the innermost frame
    in such a kind's modules, K the kind whose ``run`` is on the traceback, else the kinds of that
    plugin); None when no frame is such code."""
    import traceback

    owners: dict[str, set[str]] = {}  # a plugin's (or a user's) modules -> its kinds
    runs = {}  # code object of each such kind's run -> its name
    foreign = _foreign_kinds()
    for name, plugin in PLUGINS.items():
        run = REGISTRY[name].run if name in REGISTRY else None
        for module in {plugin.module, getattr(run, "__module__", None) or plugin.module}:
            owners.setdefault(module, set()).add(name)
        if run is not None:
            runs[getattr(run, "__code__", None)] = name
    for name, module in foreign.items():
        owners.setdefault(module, set()).add(name)
        runs[getattr(REGISTRY[name].run, "__code__", None)] = name
    where, kind = None, None
    for frame, _ in traceback.walk_tb(exc.__traceback__):
        module = frame.f_globals.get("__name__", "")
        owner = next((m for m in owners if module == m or module.startswith(f"{m}.")), None)
        if owner is not None:
            where = (module, owner)
            kind = runs.get(frame.f_code, kind)
    if where is None:
        return None
    module, owner = where
    names = sorted(owners[owner]) if kind is None else [kind]
    what = f"method kind {names[0]!r}" if len(names) == 1 else "method kinds " + ", ".join(map(repr, names))
    origin = PLUGINS[names[0]] if names[0] in PLUGINS else "registered by that module, not by pmsr_nn"
    return f"{what} of module {module} ({origin})"


PRODUCTS = {"measurements": "each target's own measurement stream (association known)",
            "detections": "per-pair detections with misses and clutter (association unknown)",
            "truth": "the designed flights themselves, nothing drawn (a bound's row)",
            "rd_maps": "per transmitter-receiver pair and frame, a range-Doppler map (track-before-detect)"}
"""What each product a kind reads is (:mod:`pmsr_nn.simulation.products`)."""

ELSEWHERE = (
    (("micmb", "mb", "mbm", "mb_tbd", "tbd", "track_before_detect"),
     "the track-before-detect filters are kinds pmb, icmb, modified_icmb and detect_then_track (they read the "
     "range-Doppler maps of a scenario's rd_maps section; e.g. evaluate/remotesensing2020_icmb.yaml)"),
    (("phd", "smcphd", "gtda", "hungarian", "known_association_kf"),
     "SMC-PHD with GTDA or Hungarian labelling is kind smc_phd (Cartesian, every pair) or smc_phd_pair (one "
     "pair's bistatic range and range-rate, e.g. evaluate/daniyan_smcphd.yaml), option labelling: gtda | hungarian "
     "(| none for smc_phd_pair); its known-association reference is kind known_association_kf_pair"),
    (("crb", "bound", "pcrlb", "cramer_rao"),
     "the posterior Cramer-Rao bound is kind pcrb (a row of a scenario of designed targets; options bound, q)"),
    (("jpda_learned_gain",),
     "the hybrid tracker (S-MSJPDA with a learned gain correction) was removed from the package under issue 56, "
     "dominated by bp and nebp (evaluate/RESULTS.md; its code is at commit c270857)"),
)
"""Names a user may try for trackers that are not method kinds, and where they live."""


def method_kind(name: str) -> MethodKind:
    """The kind ``name``, or a one-line error that names the nearest kinds, or where a tracker
    that is not a method kind lives."""
    import difflib

    kinds = registry()
    if name in kinds:
        return kinds[name]
    key = str(name).lower().replace("-", "_").replace(" ", "_")
    for names, where in ELSEWHERE:
        if key in names:
            raise ConfigError(f"unknown method kind {name!r}: {where}")
    near = difflib.get_close_matches(key, list(kinds), n=3, cutoff=0.6)
    hint = f" (did you mean {' or '.join(near)}?)" if near else ""
    raise ConfigError(f"unknown method kind {name!r}{hint}; known: {', '.join(sorted(kinds))} "
                      "('pmsr methods' describes each)")


def method_stream(name: str) -> int:
    """A stable integer naming a method's random stream (independent of its place in the list)."""
    return zlib.crc32(name.encode())
