"""Stone Soup interoperability (written against Stone Soup 1.9.1: ``pip install "pmsr-nn[stonesoup]"``).

Importing this module imports Stone Soup; without it the import raises a one-line
:class:`~pmsr_nn.errors.ConfigError`. No other module of the package imports this one at import
time (the ``stonesoup`` method kind imports it when a scenario uses it).

Models
------
* :class:`BistaticMeasurement`: one of our :class:`~pmsr_nn.measurements.MeasurementModel`
  (bistatic range, range-rate, Doppler, delay and azimuth per transmitter-receiver pair, our state
  layout and row order) as a Stone Soup ``NonLinearGaussianMeasurement``, which Stone Soup lacks:
  ``function`` is our ``h``, ``jacobian`` our analytic Jacobian, ``covar`` our ``R``. Azimuth rows
  are Stone Soup ``Bearing`` values, so a residual ``z - h(x)`` that Stone Soup takes wraps to
  (-pi, pi] as our ``residual`` does (Stone Soup's interval is [-pi, pi); they differ only at pi).
  It is a Stone Soup ``ReversibleModel``: ``inverse_function`` gives the planar position one
  pair's bistatic range (or delay) and azimuth fix (the bistatic ellipse with foci at the
  transmitter and the receiver, cut by the ray from the receiver), what Stone Soup's measurement
  initiators start a track from.
* :class:`KinematicTransition`: one of our :class:`~pmsr_nn.motion.KinematicModel` (``cv``,
  ``cv_continuous``, ``ca``) with its ``q`` as a Stone Soup ``LinearGaussianTransitionModel``:
  our ``F(dt)`` and ``Q(dt, q)``. For ``ca`` it equals Stone Soup's ``ConstantAcceleration`` per
  axis, for ``cv_continuous`` its ``ConstantVelocity`` (tests/test_stonesoup_interop.py checks
  both); our discrete ``cv`` has no Stone Soup counterpart.

Data
----
Scan ``k`` is at ``start + k dt`` (:func:`scan_times`; default start :data:`EPOCH`). Arrays may be
numpy or torch, float64, SI units.

* truth ``(K, n)`` <-> ``GroundTruthPath`` (:func:`ground_truth_path`, :func:`path_states`);
* a per-target stream ``(K, m)`` -> ``Detection`` list (:func:`stream_detections`);
* detections ``z (K, L, M, d)`` with ``valid (K, L, M)``, one run of our
  :class:`~pmsr_nn.simulation.detections.Scans` (``L`` lists: sensors) -> per scan and list a
  ``Detection`` list (:func:`scan_detections`), and the per-scan sets a Stone Soup tracker's
  detector yields (:func:`detector_feed`);
* Stone Soup ``Track`` s, per run -> :class:`~pmsr_nn.trackers.base.Estimates`
  (:func:`tracks_to_estimates`).
"""

from __future__ import annotations

import datetime
import functools
from typing import Sequence

import numpy as np
import torch

from ..errors import ConfigError
from ..measurements import MeasurementModel
from ..motion import KinematicModel
from ..trackers.base import Estimates

MISSING = 'Stone Soup is not installed: pip install "pmsr-nn[stonesoup]"'
"""The one-line error of every use of this module without Stone Soup."""

try:
    from stonesoup.base import Property
    from stonesoup.models.base import ReversibleModel, TimeVariantModel
    from stonesoup.models.measurement.nonlinear import NonLinearGaussianMeasurement
    from stonesoup.models.transition.linear import LinearGaussianTransitionModel
    from stonesoup.types.angle import Bearing
    from stonesoup.types.array import CovarianceMatrix, StateVector, StateVectors
    from stonesoup.types.detection import Detection
    from stonesoup.types.groundtruth import GroundTruthPath, GroundTruthState
    from stonesoup.types.state import GaussianState
except ImportError:
    raise ConfigError(MISSING) from None

EPOCH = datetime.datetime(2000, 1, 1)
"""Timestamp of scan 0 unless a caller gives another."""


def _np(a) -> np.ndarray:
    """A float64 numpy array of a tensor or array-like."""
    if torch.is_tensor(a):
        return a.detach().cpu().to(torch.float64).numpy()
    return np.asarray(a, dtype=np.float64)


def _vectors(values: np.ndarray, angle_rows: Sequence[int]):
    """``values (m, M)`` as a Stone Soup ``StateVector`` (M = 1) or ``StateVectors``, angle rows as
    ``Bearing`` (object dtype; plain float64 when there is no angle row)."""
    if len(angle_rows):
        out = values.astype(object)
        for r in angle_rows:
            out[r] = [Bearing(v) for v in values[r]]
        values = out
    return StateVector(values) if values.shape[1] == 1 else StateVectors(values)


# --------------------------------------------------------------------------------------- models


class BistaticMeasurement(NonLinearGaussianMeasurement, ReversibleModel):
    """Our measurement model as a Stone Soup one (module docstring); build it with
    :func:`measurement_model`. ``mapping`` lists the state rows it reads (positions, velocities)."""

    model: MeasurementModel = Property(doc="our measurement model: geometry, components, layout, deviations")

    @property
    def ndim_meas(self) -> int:
        return self.model.dim_z

    @functools.cached_property
    def angle_rows(self) -> list[int]:
        """Measurement rows that are angles (``Bearing`` values)."""
        return torch.nonzero(self.model.angle_mask).flatten().tolist()

    def function(self, state, noise=False, **kwargs):
        """``h(x) (+ noise)`` of ``state.state_vector (n, M)`` as ``(m, M)`` Stone Soup vectors
        (m, m/s, Hz, s, rad); ``noise``: ``True`` draws it from ``covar()``, an array adds it."""
        X = np.asarray(state.state_vector, dtype=np.float64)
        z = self.model.h(torch.from_numpy(np.ascontiguousarray(X.T))).numpy().T
        if isinstance(noise, bool) or noise is None:
            if noise:
                z = z + np.asarray(self.rvs(num_samples=z.shape[1], **kwargs), dtype=np.float64)
        else:
            z = z + np.asarray(noise, dtype=np.float64)
        return _vectors(z, self.angle_rows)

    def jacobian(self, state, **kwargs) -> np.ndarray:
        """Our analytic Jacobian ``dh/dx (m, n)`` at ``state.state_vector (n, 1)``."""
        x = np.asarray(state.state_vector, dtype=np.float64)[:, 0]
        return self.model.jacobian(torch.from_numpy(np.ascontiguousarray(x))).numpy()

    @functools.cached_property
    def fix_rows(self) -> tuple[int, float, int, np.ndarray, np.ndarray] | None:
        """What :meth:`inverse_function` reads: the first pair with a range (or delay) and an
        azimuth row, as ``(range row, metres per unit of that row, azimuth row, tx, rx)``;
        ``None`` when no pair has both or the geometry is not planar."""
        from .. import SPEED_OF_LIGHT

        if self.model.geometry.dim != 2:
            return None
        labels = self.model.labels
        tx, rx = self.model.geometry.pair_tx_positions().numpy(), self.model.geometry.pair_rx_positions().numpy()
        for n in range(self.model.n_pairs):
            az = f"azimuth_{n + 1}"
            for comp, scale in (("range", 1.0), ("delay", SPEED_OF_LIGHT)):
                if f"{comp}_{n + 1}" in labels and az in labels:
                    return labels.index(f"{comp}_{n + 1}"), float(scale), labels.index(az), tx[n], rx[n]
        return None

    def _fix(self, z: np.ndarray) -> np.ndarray | None:
        """The planar position a measurement ``z (m,)`` fixes (:meth:`inverse_function`), or
        ``None`` where its bistatic range is not above the baseline."""
        rows = self.fix_rows
        if rows is None:
            raise NotImplementedError(f"no pair of {self.model.labels} has a range (or delay) and an azimuth in a "
                                      "planar geometry: a measurement fixes no position")
        r_row, scale, a_row, tx, rx = rows
        S, az = float(z[r_row]) * scale, float(z[a_row])
        d = rx - tx
        base = float(np.hypot(d[0], d[1]))
        if not S > base:
            return None
        ray = np.array([np.sin(az), np.cos(az)])  # clockwise from north
        # |rx + r ray - tx| = S - r  <=>  r = (S^2 - |d|^2) / (2 (S + d . ray)), and S + d . ray >= S - |d| > 0
        r = (S - base) * (S + base) / (2.0 * (S + float(d @ ray)))
        return rx + r * ray

    def fixes_position(self, detection) -> bool:
        """Whether ``detection`` fixes a position: its bistatic range exceeds the pair's
        baseline (clutter below it lies on no bistatic ellipse); ``False`` for a model whose
        measurements fix none."""
        if self.fix_rows is None:
            return False
        return self._fix(np.asarray(detection.state_vector, dtype=np.float64)[:, 0]) is not None

    def inverse_function(self, detection, **kwargs) -> StateVector:
        """The state ``(n, 1)`` whose position is the detection's fix (first pair with a range or
        delay and an azimuth: the bistatic ellipse with foci tx, rx cut by the ray from rx; ``h``
        of it gives back that range and azimuth), zero elsewhere. Raises ``NotImplementedError``
        for a model whose measurements fix no position (Stone Soup's initiators can skip those)
        and ``ValueError`` for a range not above the baseline (:meth:`fixes_position`)."""
        pos = self._fix(np.asarray(detection.state_vector, dtype=np.float64)[:, 0])
        if pos is None:
            raise ValueError("the bistatic range is not above the baseline: the detection fixes no position")
        x = np.zeros((self.ndim_state, 1))
        x[list(self.model.pos_idx), 0] = pos
        return StateVector(x)


def measurement_model(model: MeasurementModel, ndim_state: int, noise_std=None) -> BistaticMeasurement:
    """``model`` for states of ``ndim_state`` entries, noise ``R`` from its deviations (or from
    per-component ``noise_std`` ``(C,)`` in the components' units)."""
    if ndim_state <= max(*model.pos_idx, *model.vel_idx):
        raise ConfigError(f"a {ndim_state}-entry state can not hold the model's positions {model.pos_idx} and "
                          f"velocities {model.vel_idx}")
    R = model.R(noise_std).numpy()
    return BistaticMeasurement(ndim_state=ndim_state, mapping=tuple(model.pos_idx) + tuple(model.vel_idx),
                               noise_covar=CovarianceMatrix(R), model=model)


@functools.lru_cache(maxsize=256)
def _transition(motion: KinematicModel, q, dt: float) -> tuple[np.ndarray, np.ndarray]:
    qt = torch.tensor(q, dtype=torch.float64) if isinstance(q, tuple) else q
    return motion.F(dt).numpy(), motion.Q(dt, qt).numpy()


class KinematicTransition(LinearGaussianTransitionModel, TimeVariantModel):
    """Our motion model as a Stone Soup transition model (module docstring); build it with
    :func:`transition_model`."""

    motion: KinematicModel = Property(doc="our motion model (state layout, F and Q per unit q)")
    q: float | tuple = Property(doc="process-noise intensity in the motion model's unit, or one per axis")

    @property
    def ndim_state(self) -> int:
        return self.motion.dim_x

    def matrix(self, time_interval: datetime.timedelta, **kwargs) -> np.ndarray:
        """``F (n, n)`` over ``time_interval`` (zero gives the identity)."""
        return _transition(self.motion, self.q, time_interval.total_seconds())[0].copy()

    def covar(self, time_interval: datetime.timedelta, **kwargs) -> CovarianceMatrix:
        """``Q (n, n)`` over ``time_interval`` (zero gives zeros)."""
        return CovarianceMatrix(_transition(self.motion, self.q, time_interval.total_seconds())[1].copy())


def transition_model(motion: KinematicModel, q) -> KinematicTransition:
    """``motion`` with intensity ``q`` (a float, or a tensor / sequence of one per axis)."""
    qa = _np(q)
    if qa.ndim == 0:
        q = float(qa)
    elif qa.shape == (motion.spatial_dim,):
        q = tuple(float(v) for v in qa)
    else:
        raise ConfigError(f"q must be a number or one per axis ({motion.spatial_dim}), got shape {qa.shape}")
    motion.Q(1.0, torch.tensor(q, dtype=torch.float64))  # checks q (finite, non-negative)
    return KinematicTransition(motion=motion, q=q)


# ----------------------------------------------------------------------------------------- data


def scan_times(K: int, dt: float, start: datetime.datetime = EPOCH) -> list[datetime.datetime]:
    """Timestamps of scans ``0..K-1``, ``dt`` s apart."""
    return [start + datetime.timedelta(seconds=k * dt) for k in range(K)]


def _scan_of(timestamp: datetime.datetime, K: int, dt: float, start: datetime.datetime) -> int:
    """Scan index of ``timestamp`` on the grid ``start + k dt``; a one-line error off the grid."""
    f = (timestamp - start).total_seconds() / dt
    k = round(f)
    if abs(f - k) > 1e-6 or not 0 <= k < K:
        raise ConfigError(f"timestamp {timestamp} is not one of the {K} scans {dt} s apart from {start}")
    return k


def gaussian_state(x, P, timestamp: datetime.datetime) -> GaussianState:
    """A Stone Soup Gaussian of mean ``x (n,)`` and covariance ``P (n, n)``."""
    return GaussianState(StateVector(_np(x).copy()), CovarianceMatrix(_np(P).copy()), timestamp=timestamp)


def ground_truth_path(x, dt: float, start: datetime.datetime = EPOCH, path_id: str | None = None) -> GroundTruthPath:
    """True states ``x (K, n)`` as a path with one state per scan; rows holding NaN (the target
    is not alive there) are left out. ``path_id``: the path's id (default: Stone Soup's random one)."""
    x = _np(x)
    times = scan_times(len(x), dt, start)
    states = [GroundTruthState(StateVector(x[k].copy()), timestamp=times[k]) for k in range(len(x))
              if np.isfinite(x[k]).all()]
    return GroundTruthPath(states) if path_id is None else GroundTruthPath(states, id=path_id)


def path_states(path, K: int, dt: float, start: datetime.datetime = EPOCH) -> np.ndarray:
    """The states ``(K, n)`` of a path (or track) on the scan grid, NaN at scans it has none of;
    of several states at one scan, the last."""
    if not len(path):
        raise ConfigError("the path has no state")
    out = np.full((K, path[0].state_vector.shape[0]), np.nan)
    for s in path:
        out[_scan_of(s.timestamp, K, dt, start)] = np.asarray(s.state_vector, dtype=np.float64)[:, 0]
    return out


def stream_detections(z, model: BistaticMeasurement, dt: float, start: datetime.datetime = EPOCH) -> list[Detection]:
    """One target's measurements ``z (K, m)`` (``model``'s rows and units) as detections, scan
    ``k`` at ``start + k dt``; a row with a NaN (no measurement) is left out."""
    z = _np(z)
    if z.ndim != 2 or z.shape[1] != model.ndim_meas:
        raise ConfigError(f"measurements must be (K, {model.ndim_meas}), got shape {z.shape}")
    times = scan_times(len(z), dt, start)
    return [Detection(_vectors(z[k][:, None], model.angle_rows), timestamp=times[k], measurement_model=model,
                      metadata={"scan": k}) for k in range(len(z)) if np.isfinite(z[k]).all()]


def scan_detections(z, valid, models: Sequence, dt: float, start: datetime.datetime = EPOCH,
                    origin=None) -> list[list[list[Detection]]]:
    """Padded detection lists ``z (K, L, M, d)``, ``valid (K, L, M)`` (one run of a
    :class:`~pmsr_nn.simulation.detections.Scans`) as ``out[k][l]``: the valid detections of list
    ``l`` at scan ``k``, in list order, each with ``models[l]`` (any Stone Soup measurement model
    whose rows are the ``d`` values) and metadata ``scan``, ``list`` and, where ``origin (K, L, M)``
    is given, ``origin`` (truth: a target index, or -1 for clutter). Lists, not sets, so that a
    tracker meets the detections in the same order on every run (a Stone Soup associator takes
    either)."""
    z, valid = _np(z), np.asarray(valid.numpy() if torch.is_tensor(valid) else valid, dtype=bool)
    K, L, M, d = z.shape
    if valid.shape != (K, L, M) or len(models) != L:
        raise ConfigError(f"need valid (K, L, M) = {(K, L, M)} and {L} measurement models, got {valid.shape} and "
                          f"{len(models)}")
    origin = None if origin is None else (origin.numpy() if torch.is_tensor(origin) else np.asarray(origin))
    angles = [getattr(mm, "angle_rows", []) for mm in models]
    times = scan_times(K, dt, start)
    out = []
    for k in range(K):
        lists = []
        for l in range(L):
            keep = np.flatnonzero(valid[k, l])
            lists.append([Detection(_vectors(z[k, l, i][:, None], angles[l]), timestamp=times[k],
                                    measurement_model=models[l],
                                    metadata={"scan": k, "list": l} if origin is None else
                                    {"scan": k, "list": l, "origin": int(origin[k, l, i])}) for i in keep])
        out.append(lists)
    return out


def detector_feed(detections: list[list[list[Detection]]], dt: float,
                  start: datetime.datetime = EPOCH) -> list[tuple[datetime.datetime, set[Detection]]]:
    """:func:`scan_detections`'s output as a Stone Soup tracker's detector: per scan ``(time, set
    of every list's detections)``."""
    times = scan_times(len(detections), dt, start)
    return [(times[k], {det for lst in lists for det in lst}) for k, lists in enumerate(detections)]


def tracks_to_estimates(tracks: Sequence[Sequence], K: int, dt: float, ndim_state: int,
                        start: datetime.datetime = EPOCH, reported: Sequence[Sequence] | None = None,
                        paired: bool | None = None) -> Estimates:
    """Stone Soup tracks (any sequence of states with ``state_vector``, ``timestamp`` and,
    where Gaussian, ``covar``) per run, ``tracks[b][i]``, as estimates ``x (B, K, N, n)`` with slot
    ``i`` = track ``i`` of its run (``N`` the most tracks of a run; a run with fewer leaves its last
    slots empty): a slot exists at the scans its track has a state at (the last of several at one
    scan, e.g. one per sensor) and, where ``reported[b][i] = (first, end)`` is given, only at
    scans ``first <= k < end`` (where a tracker reported the track: confirmed and not deleted;
    states before, e.g. of its tentative start, are left out); ``x`` and ``P`` are NaN elsewhere;
    ``P`` is ``None`` when no state has a covariance. ``paired``: slot ``i`` is target ``i``
    (:class:`~pmsr_nn.trackers.base.Estimates`); default: without ``reported`` (tracks a tracker
    started itself come with the scans it reported them at)."""
    B, N, n = len(tracks), max((len(t) for t in tracks), default=0), ndim_state
    if reported is not None and [len(r) for r in reported] != [len(t) for t in tracks]:
        raise ConfigError(f"reported needs one (first, end) per track: {[len(t) for t in tracks]} tracks per run, got "
                          f"{[len(r) for r in reported]}")
    x = np.full((B, K, N, n), np.nan)
    P = np.full((B, K, N, n, n), np.nan)
    exists = np.zeros((B, K, N), dtype=bool)
    has_covar = False
    for b, run in enumerate(tracks):
        for i, track in enumerate(run):
            first, end = (0, K) if reported is None else (int(v) for v in reported[b][i])
            for s in track:
                k = _scan_of(s.timestamp, K, dt, start)
                if not first <= k < end:
                    continue
                sv = np.asarray(s.state_vector, dtype=np.float64)
                if sv.shape != (n, 1):
                    raise ConfigError(f"run {b}, track {i}: a state of {sv.shape[0]} entries, expected {n}")
                x[b, k, i], exists[b, k, i] = sv[:, 0], True
                covar = getattr(s, "covar", None)
                if covar is not None:
                    P[b, k, i], has_covar = np.asarray(covar, dtype=np.float64), True
    return Estimates(torch.from_numpy(x), torch.from_numpy(exists), torch.from_numpy(P) if has_covar else None,
                     paired=reported is None if paired is None else bool(paired))
