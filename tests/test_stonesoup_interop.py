"""Stone Soup interoperability (pmsr_nn.interop.stonesoup) and the method kind stonesoup.

Tolerances: Stone Soup and we compute the same float64 formulas in a different order (its gain
``C S^-1`` and ``P - K S K^T``, our Cholesky solves and ``P - W^T W``), so results differ by
round-off only. Differences are measured in units of the state's own deviation (``|dx_i| /
sd_i``, ``|dP_ij| / (sd_i sd_j)``), which is scale-free across metres and m/s^2; 1e-8 leaves
three orders of magnitude above the ~1e-11 measured over 300 steps (the test runs 150), while any real difference (a
missed wrap, another Q, a step out of order) is of order 1.
"""

from __future__ import annotations

import datetime
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from pmsr_nn.config import load_yaml
from pmsr_nn.errors import ConfigError
from pmsr_nn.harness import evaluate
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario
from pmsr_nn.harness.scenario.method_spec import MethodSpec
from pmsr_nn.methods import method_kind

ROOT = Path(__file__).resolve().parents[1]
TOL = 1e-8


def _small_mt(tmp_path: Path, methods: list[dict], **over) -> Path:
    """evaluate/stonesoup_jpda.yaml cut to 2 runs of 6 scans, 2 targets, 5 clutter points."""
    data = load_yaml(ROOT / "evaluate" / "stonesoup_jpda.yaml")
    data.update(mc_runs=2, block_runs=2, warmup_steps=2, methods=methods)
    data["world"]["scans"] = 6
    data["detections"]["clutter"]["per_scan"] = 5
    for case in data["cases"]:
        case["formation"] = {**case["formation"], "count": 2}
    data["reference"]["file"] = str(ROOT / "evaluate" / "reference" / "paper_tables.json")
    data.update(over)
    p = tmp_path / "ss.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _sd_scaled(a: np.ndarray, b: np.ndarray, P: np.ndarray) -> tuple[float, float]:
    """Largest ``|a_x - b_x| / sd`` and ``|a_P - b_P| / (sd sd^T)`` (``a``, ``b``: (x, P) pairs, P
    giving the deviations)."""
    sd = np.sqrt(np.diagonal(P, axis1=-2, axis2=-1))
    return (float(np.max(np.abs(a[0] - b[0]) / sd)),
            float(np.max(np.abs(a[1] - b[1]) / (sd[..., :, None] * sd[..., None, :]))))


# ------------------------------------------------------------------------- without Stone Soup


@pytest.mark.integration
def test_nothing_imports_stonesoup_at_import_time():
    code = ("import sys; import pmsr_nn, pmsr_nn.interop, pmsr_nn.harness, pmsr_nn.cli; from pmsr_nn.methods import "
            "registry; assert 'stonesoup' in registry(); bad = sorted(m for m in sys.modules if m == 'stonesoup' or "
            "m.startswith('stonesoup.')); assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, timeout=120)


def test_without_stonesoup_the_kind_is_listed_and_a_scenario_fails_at_load(tmp_path, monkeypatch):
    # `import stonesoup` (and of any submodule an earlier test left in sys.modules) raises ImportError
    for name in [m for m in sys.modules if m.startswith("stonesoup.")] + ["stonesoup"]:
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.delitem(sys.modules, "pmsr_nn.interop.stonesoup", raising=False)
    import pmsr_nn.interop

    monkeypatch.delattr(pmsr_nn.interop, "stonesoup", raising=False)  # `from ..interop import stonesoup` reads it
    assert method_kind("stonesoup").reads == "detections"
    with pytest.raises(ConfigError) as exc:
        import pmsr_nn.interop.stonesoup  # noqa: F401
    assert str(exc.value) == 'Stone Soup is not installed: pip install "pmsr-nn[stonesoup]"'
    path = _small_mt(tmp_path, [{"name": "S-MSJPDA", "kind": "s_msjpda"}, {"name": "SS", "kind": "stonesoup"}])
    with pytest.raises(ConfigError) as exc:
        evaluate(path, tmp_path / "out", progress=False)
    msg = str(exc.value)
    assert "\n" not in msg and "'SS'" in msg and 'pip install "pmsr-nn[stonesoup]"' in msg
    assert not (tmp_path / "out").exists()


def test_tracker_option_is_a_checked_choice(tmp_path):
    assert MethodSpec("a", "stonesoup", options={"tracker": "gnn"}).option("tracker") == "gnn"
    assert MethodSpec("a", "stonesoup").option("tracker") == "jpda"
    for bad in ("mht", 3, None):
        with pytest.raises(ConfigError, match="option tracker must be one of jpda, gnn") as exc:
            MethodSpec("a", "stonesoup", options={"tracker": bad})
        assert "\n" not in str(exc.value)
    with pytest.raises(ConfigError, match="option tracker must be one of jpda, gnn"):
        evaluate(_small_mt(tmp_path, [{"name": "SS", "kind": "stonesoup", "options": {"tracker": "mht"}}]),
                 tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_initiation_option_is_a_checked_choice():
    assert MethodSpec("a", "stonesoup").option("initiation") == "oracle"
    assert MethodSpec("a", "stonesoup", options={"initiation": "detections"}).option("initiation") == "detections"
    with pytest.raises(ConfigError, match="option initiation must be one of oracle, detections") as exc:
        MethodSpec("a", "stonesoup", options={"initiation": "births"})
    assert "\n" not in str(exc.value)
    with pytest.raises(ConfigError, match="option confirm_points must be an integer") as exc:
        MethodSpec("a", "stonesoup", options={"initiation": "detections", "confirm_points": 2.5})
    assert "\n" not in str(exc.value)


# ---------------------------------------------------------------------------------- the models


def _stream_models():
    """The stream model (CA, range / range-rate / azimuth, component layout) of the default recipe."""
    from pmsr_nn.simulation.recipe import TrackRecipe
    from pmsr_nn.simulation.tracks import build_models

    return build_models(TrackRecipe())


def _mt_models():
    """The multi-target model (CV, range / Doppler, pair layout) of evaluate/stonesoup_jpda.yaml."""
    setup = prepare(load_scenario(ROOT / "evaluate" / "stonesoup_jpda.yaml"))
    return setup.models.motion, setup.cases[0].sensing.detection_model


@pytest.mark.parametrize("which", ["stream", "detections"])
def test_measurement_model_is_ours(which):
    pytest.importorskip("stonesoup")
    from stonesoup.types.angle import Bearing
    from stonesoup.types.array import StateVectors
    from stonesoup.types.state import State

    from pmsr_nn.interop import stonesoup as ss

    motion, model = _stream_models() if which == "stream" else _mt_models()
    n = motion.dim_x
    mm = ss.measurement_model(model, n)
    g = torch.Generator().manual_seed(1)
    x = torch.randn(5, n, generator=g, dtype=torch.float64) * torch.tensor([3000.0, 20.0, 0.1] * 2 if n == 6 else
                                                                           [3000.0, 20.0] * 2, dtype=torch.float64)
    x[:, list(motion.pos_idx)] += torch.tensor([-20000.0, -15000.0], dtype=torch.float64)
    z = mm.function(State(StateVectors(x.numpy().T)))
    assert z.shape == (model.dim_z, 5) and mm.ndim_meas == model.dim_z and mm.ndim_state == n
    np.testing.assert_array_equal(np.asarray(z, dtype=np.float64).T[:, ~model.angle_mask.numpy()],
                                  model.h(x).numpy()[:, ~model.angle_mask.numpy()])
    angles = model.angle_mask.numpy()
    assert angles.sum() == (3 if which == "stream" else 0)  # azimuth per pair in the stream; range-Doppler has none
    bearing = np.vectorize(lambda v: isinstance(v, Bearing))(np.asarray(z))
    assert np.array_equal(bearing, np.broadcast_to(angles[:, None], bearing.shape))  # Bearing exactly on angle rows
    # Bearing wraps to [-pi, pi): the same angle as ours to round-off
    assert np.allclose(np.asarray(z, dtype=np.float64).T[:, angles], model.h(x).numpy()[:, angles], rtol=0, atol=1e-15)
    for i in range(5):
        np.testing.assert_array_equal(mm.jacobian(State(x[i].numpy()[:, None])), model.jacobian(x[i]).numpy())
    np.testing.assert_array_equal(mm.covar(), model.R().numpy())


def test_azimuth_residual_wraps_as_ours():
    """A target due south of the receiver: predicted azimuth just under pi, measured just over
    -pi. Stone Soup's EKF update (Bearing rows) equals ours (wrapped residual); without the wrap
    the innovation would be 2 pi off."""
    pytest.importorskip("stonesoup")
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    from pmsr_nn.filters import Gaussian, kalman_update, linearised_moments
    from pmsr_nn.interop import stonesoup as ss
    from pmsr_nn.measurements import wrap_angle

    motion, model = _stream_models()
    rx = model.geometry.receivers[0].position_m
    x = torch.tensor([rx[0] + 5.0, 10.0, 0.0, rx[1] - 8000.0, 3.0, 0.0], dtype=torch.float64)
    P = torch.diag(torch.tensor([400.0, 9.0, 0.01] * 2, dtype=torch.float64))
    z = model.h(x)
    az = model.angle_mask
    assert bool((z[az].abs() > 3.1).any())
    z = torch.where(az, wrap_angle(z + 0.003), z + torch.tensor(1.0, dtype=torch.float64))
    assert bool(((z[az] < 0) & (model.h(x)[az] > 0)).any())  # the measurement crosses the cut
    ours, nu, _ = kalman_update(Gaussian(x, P), z, linearised_moments(Gaussian(x, P), model, model.R()), model)
    assert float(nu[az].abs().max()) < 0.01
    mm = ss.measurement_model(model, 6)
    det = ss.stream_detections(z[None], mm, 1.0)[0]
    post = ExtendedKalmanUpdater(measurement_model=mm).update(SingleHypothesis(ss.gaussian_state(x, P, det.timestamp), det))
    dx, dP = _sd_scaled((np.asarray(post.state_vector, dtype=np.float64)[:, 0], np.asarray(post.covar)),
                        (ours.x.numpy(), ours.P.numpy()), ours.P.numpy())
    assert dx < TOL and dP < TOL


def test_inverse_function_fixes_the_position_our_model_measures():
    """A pair's bistatic range and azimuth fix a planar position (ellipse with foci tx, rx cut by
    the ray from rx): h(inverse(z)) gives back z's range and azimuth, for each pair of the stream
    model (component layout) and of the detection model (pair layout, and delay instead of range);
    a range below the baseline fixes none, a model without azimuth is not invertible."""
    pytest.importorskip("stonesoup")
    from stonesoup.models.base import ReversibleModel
    from stonesoup.types.detection import Detection

    from pmsr_nn.interop import stonesoup as ss
    from pmsr_nn.measurements import MeasurementModel

    motion, model = _stream_models()
    g = torch.Generator().manual_seed(3)
    x = torch.zeros(40, motion.dim_x, dtype=torch.float64)
    x[:, list(motion.pos_idx)] = (torch.rand(40, 2, generator=g, dtype=torch.float64) - 0.5) * 30000.0
    x[:, list(motion.vel_idx)] = torch.randn(40, 2, generator=g, dtype=torch.float64) * 20.0
    delay = MeasurementModel(model.geometry, ("delay", "doppler", "azimuth"), (1e-7, 5.0, 0.05), model.pos_idx,
                             model.vel_idx, layout="pair")
    checked = 0
    for base in (model, delay):
        for pairs in ([0], [1], [2], [1, 0, 2]):
            sub = base.for_pairs(pairs)
            mm = ss.measurement_model(sub, motion.dim_x)
            # the contract Stone Soup's initiators test before they call inverse_function
            assert isinstance(mm, ReversibleModel)
            r_row, _, a_row, _, _ = mm.fix_rows
            assert sub.labels[r_row].split("_")[0] in ("range", "delay") and sub.labels[a_row].startswith("azimuth_")
            z = sub.h(x)
            for i in range(len(x)):
                det = Detection(ss._vectors(z[i].numpy()[:, None], mm.angle_rows), measurement_model=mm)
                assert mm.fixes_position(det)
                back = np.asarray(mm.inverse_function(det), dtype=np.float64)
                assert back.shape == (motion.dim_x, 1)
                assert not back[list(motion.vel_idx)].any()  # only the position is fixed
                zb = sub.h(torch.from_numpy(back[:, 0])).numpy()
                for row in (r_row, a_row):
                    assert abs(zb[row] - float(z[i, row])) <= 1e-9 * abs(float(z[i, row])), (pairs, i, row)
                np.testing.assert_allclose(back[list(motion.pos_idx), 0], x[i, list(motion.pos_idx)].numpy(),
                                           rtol=0, atol=1e-6)
                checked += 1
    assert checked == 2 * 4 * 40
    # clutter below the baseline lies on no ellipse
    mm = ss.measurement_model(model.for_pairs([0]), motion.dim_x)
    z = model.for_pairs([0]).h(x[0])
    z[mm.fix_rows[0]] = 0.9 * model.geometry.baselines_m()[0]
    det = Detection(ss._vectors(z.numpy()[:, None], mm.angle_rows), measurement_model=mm)
    assert not mm.fixes_position(det)
    with pytest.raises(ValueError, match="not above the baseline"):
        mm.inverse_function(det)
    # range-Doppler (no azimuth): no fix
    _, rd = _mt_models()
    mm = ss.measurement_model(rd.for_pairs([0]), 4)
    assert mm.fix_rows is None
    det = Detection(ss._vectors(np.array([[9000.0], [3.0]]), []), measurement_model=mm)
    assert not mm.fixes_position(det)
    with pytest.raises(NotImplementedError, match="fixes no position"):
        mm.inverse_function(det)


def test_transition_is_ours_and_stone_soups_own():
    pytest.importorskip("stonesoup")
    from stonesoup.models.transition.linear import (CombinedLinearGaussianTransitionModel, ConstantAcceleration,
                                                    ConstantVelocity)

    from pmsr_nn.interop import stonesoup as ss
    from pmsr_nn.motion import motion_model

    dt = datetime.timedelta(seconds=2.5)
    for name, theirs, dims, q in (("ca", ConstantAcceleration, 2, 0.3), ("cv_continuous", ConstantVelocity, 2, 5.0),
                                  ("cv_continuous", ConstantVelocity, 3, torch.tensor([5.0, 5.0, 0.05]))):
        motion = motion_model(name, dims)
        t = ss.transition_model(motion, q)
        per_axis = torch.as_tensor(q, dtype=torch.float64).expand(dims).tolist()
        other = CombinedLinearGaussianTransitionModel([theirs(v) for v in per_axis])  # same axis-major layout
        np.testing.assert_allclose(t.matrix(time_interval=dt), other.matrix(time_interval=dt), rtol=1e-15, atol=0)
        np.testing.assert_allclose(t.covar(time_interval=dt), other.covar(time_interval=dt), rtol=1e-14, atol=0)
        np.testing.assert_array_equal(t.covar(time_interval=dt), motion.Q(2.5, q).numpy())
        assert t.ndim_state == motion.dim_x
    # our discrete-acceleration CV (no Stone Soup counterpart): our F and Q; a zero interval is a no-op
    motion = motion_model("cv", 2)
    t = ss.transition_model(motion, 1.0)
    np.testing.assert_array_equal(t.matrix(time_interval=dt), motion.F(2.5).numpy())
    np.testing.assert_array_equal(t.covar(time_interval=dt), motion.Q(2.5, 1.0).numpy())
    zero = datetime.timedelta(0)
    np.testing.assert_array_equal(t.matrix(time_interval=zero), np.eye(4))
    np.testing.assert_array_equal(t.covar(time_interval=zero), np.zeros((4, 4)))
    with pytest.raises(ConfigError, match="q must be"):
        ss.transition_model(motion, [1.0, 2.0, 3.0])


def test_stone_soup_ekf_on_our_measurements_is_our_ekf(make_tracks):
    """150 steps of two CA tracks of the default recipe (range, range-rate, azimuth of three pairs,
    per-track deviations): Stone Soup's ExtendedKalmanPredictor / Updater with the converted models
    and measurements against pmsr_nn.filters.ekf (the single-target EKF row)."""
    pytest.importorskip("stonesoup")
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    from conftest import perturbed_prior
    from pmsr_nn.filters import ekf
    from pmsr_nn.interop import stonesoup as ss
    from pmsr_nn.simulation.recipe import TrackRecipe

    motion, model, batch = make_tracks(150, 2, 3)
    dt, q = TrackRecipe().motion.dt_s, TrackRecipe().effective_motion().q_psd
    prior = perturbed_prior(batch.states[:, 0])
    ours = ekf(prior, batch.measurements, motion, dt, q, model, model.R(batch.noise_std))
    predictor = ExtendedKalmanPredictor(ss.transition_model(motion, q))
    for b in range(2):
        updater = ExtendedKalmanUpdater(measurement_model=ss.measurement_model(model, motion.dim_x, batch.noise_std[b]))
        state = ss.gaussian_state(prior.x[b], prior.P[b], ss.EPOCH)
        xs, Ps = [], []
        for det in ss.stream_detections(batch.measurements[b], updater.measurement_model, dt):
            state = updater.update(SingleHypothesis(predictor.predict(state, timestamp=det.timestamp), det))
            xs.append(np.asarray(state.state_vector, dtype=np.float64)[:, 0])
            Ps.append(np.asarray(state.covar, dtype=np.float64))
        assert len(xs) == 150
        dx, dP = _sd_scaled((np.array(xs), np.array(Ps)), (ours.x[b].numpy(), ours.P[b].numpy()), ours.P[b].numpy())
        assert dx < TOL and dP < TOL, (dx, dP)


# ------------------------------------------------------------------------------ the converters


def test_truth_round_trip():
    pytest.importorskip("stonesoup")
    from pmsr_nn.interop import stonesoup as ss

    x = np.arange(40, dtype=np.float64).reshape(10, 4) * 1.5
    x[:3] = np.nan  # born at scan 3
    x[8:] = np.nan  # dead from scan 8
    start = datetime.datetime(2021, 5, 1, 12)
    path = ss.ground_truth_path(torch.from_numpy(x), 2.0, start, path_id="target 1")
    assert len(path) == 5 and path.id == "target 1"
    assert path[0].timestamp == start + datetime.timedelta(seconds=6.0)
    np.testing.assert_array_equal(ss.path_states(path, 10, 2.0, start), x)
    with pytest.raises(ConfigError, match="not one of the 10 scans"):
        ss.path_states(path, 10, 3.0, start)


def test_detections_convert_with_their_models_times_and_origins():
    pytest.importorskip("stonesoup")
    from pmsr_nn.interop import stonesoup as ss
    from pmsr_nn.rng import seeded_generator
    from pmsr_nn.simulation.detections import ClutterSpec, simulate_scans

    motion, model = _mt_models()
    truth = torch.tensor([[-25000.0, 200.0, -20000.0, 244.1]], dtype=torch.float64) \
        + torch.arange(4, dtype=torch.float64)[:, None, None] * torch.tensor([200.0, 0.0, 244.1, 0.0])
    scans = simulate_scans(truth[None], model, 0.7, ClutterSpec(per_scan=3), seeded_generator(4))  # (1, 4, 3, M, 2)
    models = [ss.measurement_model(model.for_pairs([p]), 4) for p in range(3)]
    lists = ss.scan_detections(scans.z[0], scans.valid[0], models, 2.0, origin=scans.origin[0])
    assert len(lists) == 4 and all(len(per) == 3 for per in lists)
    for k, per in enumerate(lists):
        for p, dets in enumerate(per):
            keep = scans.valid[0, k, p]
            assert len(dets) == int(keep.sum())
            np.testing.assert_array_equal(np.array([d.state_vector[:, 0] for d in dets], dtype=np.float64).reshape(-1, 2),
                                          scans.z[0, k, p][keep].numpy())
            assert [d.metadata["origin"] for d in dets] == scans.origin[0, k, p][keep].tolist()
            assert all(d.measurement_model is models[p] and d.timestamp == ss.EPOCH + datetime.timedelta(seconds=2 * k)
                       for d in dets)
    feed = ss.detector_feed(lists, 2.0)
    assert [len(s) for _, s in feed] == scans.valid[0].sum((1, 2)).tolist()
    # a stream: rows with a NaN (no measurement) are left out
    z = model.h(truth[:, 0])
    z[1] = float("nan")
    dets = ss.stream_detections(z, ss.measurement_model(model, 4), 1.0)
    assert [d.metadata["scan"] for d in dets] == [0, 2, 3]
    np.testing.assert_array_equal(np.asarray(dets[1].state_vector, dtype=np.float64)[:, 0], z[2].numpy())


def test_tracks_round_trip_to_estimates():
    pytest.importorskip("stonesoup")
    from stonesoup.types.state import State
    from stonesoup.types.track import Track

    from pmsr_nn.interop import stonesoup as ss

    g = torch.Generator().manual_seed(0)
    K, n = 6, 4
    x = torch.randn(2, K, 3, n, generator=g, dtype=torch.float64)
    A = torch.randn(2, K, 3, n, n, generator=g, dtype=torch.float64)
    P = A @ A.transpose(-1, -2)
    exists = torch.zeros(2, K, 3, dtype=torch.bool)
    exists[0, :, 0] = True
    exists[0, 2:5, 1] = True
    exists[1, 1:, 0] = True  # run 1 has one track: its other slots never exist
    times = ss.scan_times(K, 0.5)
    runs = []
    for b in range(2):
        tracks = []
        for i in range(3):
            if bool(exists[b, :, i].any()):
                states = []
                for k in torch.nonzero(exists[b, :, i]).flatten().tolist():
                    states.append(State(x[b, k, i].numpy()[:, None] + 7.0, timestamp=times[k]))  # replaced below
                    states.append(ss.gaussian_state(x[b, k, i], P[b, k, i], times[k]))  # the last at a scan counts
                tracks.append(Track(states))
        runs.append(tracks)
    est = ss.tracks_to_estimates(runs, K, 0.5, n)
    assert tuple(est.x.shape) == (2, K, 2, n)  # the most tracks of a run
    assert torch.equal(est.exists, exists[:, :, :2])
    live = est.exists
    assert torch.equal(est.x[live], x[:, :, :2][live]) and torch.equal(est.P[live], P[:, :, :2][live])
    assert bool(torch.isnan(est.x[~live]).all())


def test_reported_tracks_to_unpaired_estimates():
    """Tracks a tracker started itself: a slot exists only over the scans it reported the track
    at (its tentative start left out), runs with fewer tracks padded, estimates unpaired."""
    pytest.importorskip("stonesoup")
    from stonesoup.types.track import Track

    from pmsr_nn.interop import stonesoup as ss

    K, n = 8, 4
    times = ss.scan_times(K, 1.0)
    state = lambda k, v: ss.gaussian_state(np.full(n, float(v)), np.eye(n) * (k + 1), times[k])
    a = Track([state(k, 10 + k) for k in range(1, 7)])  # tentative at 1, confirmed at 2, deleted at 5
    b = Track([state(k, 20 + k) for k in range(3, 8)])  # confirmed at 4, never deleted
    c = Track([state(k, 30 + k) for k in range(0, 3)])
    est = ss.tracks_to_estimates([[a, b], [c]], K, 1.0, n, reported=[[(2, 5), (4, K)], [(0, 3)]])
    assert not est.paired and tuple(est.x.shape) == (2, K, 2, n)
    expect = torch.zeros(2, K, 2, dtype=torch.bool)
    expect[0, 2:5, 0] = True
    expect[0, 4:, 1] = True
    expect[1, :3, 0] = True
    assert torch.equal(est.exists, expect)
    assert est.x[0, 2, 0, 0] == 12.0 and est.x[0, 7, 1, 0] == 27.0 and est.P[0, 4, 0, 0, 0] == 5.0
    assert bool(torch.isnan(est.x[~expect]).all()) and bool(torch.isnan(est.P[~expect]).all())
    assert ss.tracks_to_estimates([[a]], K, 1.0, n).paired  # without reported: paired, as before
    with pytest.raises(ConfigError, match="one \\(first, end\\) per track"):
        ss.tracks_to_estimates([[a, b]], K, 1.0, n, reported=[[(0, 1)]])


# -------------------------------------------------------------------------- the method kind


def _two_targets(tmp_path: Path, methods: list[dict], death_a: float = 16.0, birth_b: float = 8.0,
                 flight_s: float = 24.0) -> Path:
    """A designed scenario (CA, range / range-rate / azimuth): target a lives over scans 0-15, b
    over 8-31 (by default); Pd 1 and no clutter."""
    flight = {"start_range_m": 4000.0, "start_bearing_deg": 130.0, "speed_mps": 10.0, "heading_deg": 20.0,
              "segments": [{"duration_s": flight_s}]}
    other = {"start_range_m": 7800.0, "start_bearing_deg": 140.0, "speed_mps": 12.0, "heading_deg": 0.0,
             "segments": [{"duration_s": flight_s}]}
    d = {"name": "two", "seed": 5, "mc_runs": 2, "block_runs": 2, "warmup_steps": 5, "random_streams": "per_product",
         "detections": {"pd": 1.0, "clutter": {"per_scan": 0, "range_m": [0.0, 25000.0], "range_rate_mps": [-40.0, 40.0]}},
         "cases": [{"name": "c", "targets": [{"name": "a", "death_s": death_a, **flight},
                                             {"name": "b", "birth_s": birth_b, **other}]}],
         "methods": methods}
    path = tmp_path / "two.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


@pytest.mark.parametrize("tracker", ["jpda", "gnn"])
def test_without_clutter_the_trackers_are_a_sequential_ekf_over_each_life(tmp_path, tracker):
    """Pd 1, no clutter, a gate of probability 1 - 1e-12: every association is certain (a
    missed-detection weight below 1e-15), so Stone Soup's JPDA and GNN are the EKF updated pair by
    pair, started at each target's birth from its prior and stopped at its death; checked
    against pmsr_nn.filters.sequential_update with our own predict, to 1e-8 deviations."""
    pytest.importorskip("stonesoup")
    from pmsr_nn.filters import Gaussian, linearised_moments, predict, sequential_update
    from pmsr_nn.harness.run.blocks import call_method, draw_block
    from pmsr_nn.harness.run.runner import prepare
    from pmsr_nn.harness.scenario.schema import load_scenario

    setup = prepare(load_scenario(_two_targets(tmp_path, [{"name": "SS", "kind": "stonesoup", "options": {
        "tracker": tracker, "gate_probability": 1.0 - 1e-12}}])))
    case = setup.cases[0]
    _, products = draw_block(setup, 0, 0)
    det = products["detections"]
    est = call_method(setup, setup.methods[0], case, products, (5, 0, 0))
    assert torch.equal(est.exists, case.alive.expand(2, *case.alive.shape))
    assert not bool(est.extras["dummy_most_probable"].any())
    m, model = setup.models, case.sensing.detection_model
    F, Q, R = m.motion.F(m.dt), m.motion.Q(m.dt, m.q), model.R()
    B, K, T = est.exists.shape
    z = det.scans.target_measurements(T).flatten(-2)  # (B, K, T, N d), pair layout
    assert not bool(torch.isnan(z[est.exists]).any())
    for t in range(T):
        life = torch.nonzero(case.alive[:, t]).flatten().tolist()
        g = Gaussian(det.prior.x[:, t], det.prior.P[:, t])
        for k in life:
            if k > life[0]:
                g = predict(g, F, Q)
            g, _ = sequential_update(g, z[:, k, t], model, R, linearised_moments)
            dx, dP = _sd_scaled((est.x[:, k, t].numpy(), est.P[:, k, t].numpy()), (g.x.numpy(), g.P.numpy()),
                                g.P.numpy())
            assert dx < TOL and dP < TOL, (t, k, dx, dP)
    # the predicted range deviation the loss rule reads: between R's 30 m and the prior's spread
    sd = est.extras["gate_range_sd_m"][est.exists]
    assert bool((sd > 30.0).all() and (sd < 1000.0).all())


@pytest.mark.parametrize("tracker", ["jpda", "gnn"])
def test_initiation_from_detections_starts_one_track_per_target(tmp_path, tracker):
    """Pd 1, no clutter, two well-separated targets (a over scans 0-29, b over 20-59): Stone Soup's
    own track management gives exactly one reported track per target, confirmed within
    confirm_points scans of its birth, following it, deleted within delete_after_misses + 1 scans
    of its death, and no other track; unpaired estimates without loss-rule extras."""
    pytest.importorskip("stonesoup")
    from pmsr_nn.harness.run.blocks import call_method, draw_block
    from pmsr_nn.harness.run.runner import prepare
    from pmsr_nn.harness.scenario.schema import load_scenario

    confirm, misses = 4, 3
    setup = prepare(load_scenario(_two_targets(tmp_path, [{"name": "SS", "kind": "stonesoup", "options": {
        "tracker": tracker, "initiation": "detections", "confirm_points": confirm, "delete_after_misses": misses}}],
        death_a=30.0, birth_b=20.0, flight_s=40.0)))
    case = setup.cases[0]
    truth, products = draw_block(setup, 0, 0)
    est = call_method(setup, setup.methods[0], case, products, (5, 0, 0))
    B, K, T = 2, *case.alive.shape
    assert K == 60 and not est.paired and est.extras == {} and est.x.shape[:3] == (B, K, 2)
    pos = list(setup.models.motion.pos_idx)
    for b in range(B):
        owner = []
        for i in range(2):
            scans = torch.nonzero(est.exists[b, :, i]).flatten()
            first, last = int(scans[0]), int(scans[-1])
            assert len(scans) == last - first + 1  # reported from confirmation to deletion, no gap
            d = torch.linalg.vector_norm(est.x[b, scans, i][:, pos, None].transpose(-1, -2)
                                         - truth.x[b, scans][..., pos], dim=-1)  # (scans, T)
            t = int(torch.nan_to_num(d, nan=float("inf")).min(1).indices.mode().values)
            owner.append(t)
            life = torch.nonzero(case.alive[:, t]).flatten()
            birth, death = int(life[0]), int(life[-1]) + 1
            assert birth <= first < birth + confirm, (b, i, first, birth)
            assert last < death + misses + 1 if death < K else last == K - 1, (b, i, last, death)
            assert bool((d[scans < death, t] < 1000.0).all())  # it follows its target while it lives
            assert float(d[(scans >= birth + 10) & (scans < death), t].max()) < 150.0
        assert sorted(owner) == [0, 1], owner  # one track per target, no other
        assert bool(torch.isnan(est.x[b][~est.exists[b]]).all())


def test_harness_scores_the_tracks_stone_soup_started(tmp_path):
    """Through the harness: the unpaired tracks are matched to the targets (one confirmed track
    per target, no false track) and the row says how its tracks start."""
    pytest.importorskip("stonesoup")
    path = _two_targets(tmp_path, [{"name": "SS", "kind": "stonesoup", "options": {"initiation": "detections"}}],
                        death_a=30.0, birth_b=20.0, flight_s=40.0)
    res = evaluate(path, tmp_path / "out", progress=False)
    row = res["cases"]["c"]["methods"]["SS"]
    assert row["initiation"] == "detections" and row["confirmed_tracks_per_target"] == 1.0
    assert row["false_tracks_per_run"] == 0.0 and row["fragmentations_per_run"] == 0.0
    assert row["scans_to_first_track"] <= method_kind("stonesoup").options["confirm_points"].default
    assert 0 < row["rmse_pos_m"] < 100.0


def test_initiation_from_detections_needs_range_and_azimuth(tmp_path):
    """Range-Doppler detections (no azimuth) fix no position: a one-line refusal."""
    pytest.importorskip("stonesoup")
    from pmsr_nn.harness.run.blocks import call_method, draw_block

    path = _small_mt(tmp_path, [{"name": "SS", "kind": "stonesoup", "options": {"initiation": "detections"}}])
    refusal = "starts tracks from a pair's bistatic range \\(or delay\\) and azimuth"
    with pytest.raises(ConfigError, match=refusal) as exc:
        setup = prepare(load_scenario(path))
        _, products = draw_block(setup, 0, 0)
        call_method(setup, setup.methods[0], setup.cases[0], products, (0, 0, 0))
    assert "\n" not in str(exc.value) and "'SS'" in str(exc.value)


def test_harness_reports_stone_soup_rows_with_run_time(tmp_path):
    pytest.importorskip("stonesoup")
    methods = [{"name": "S-MSJPDA", "kind": "s_msjpda"},
               {"name": "Stone Soup JPDA", "kind": "stonesoup", "options": {"tracker": "jpda"}},
               {"name": "Stone Soup GNN", "kind": "stonesoup", "options": {"tracker": "gnn"}}]
    res = evaluate(_small_mt(tmp_path, methods), tmp_path / "out", progress=False)
    rows = res["cases"]["nominal"]["methods"]
    for name in ("Stone Soup JPDA", "Stone Soup GNN"):
        r = rows[name]
        assert math.isfinite(r["seconds_per_run"]) and r["loss_probability"] in (0.0, 0.25, 0.5, 0.75, 1.0)  # of 2 runs x 2 targets
        # 1000 m range noise, priors 100 m off: a track that followed clutter would be km away
        assert 0 < r["rmse_pos_m"] < 500.0
    assert res["settings"]["methods"]["Stone Soup GNN"] == {"kind": "stonesoup", "reads": "detections",
                                                           "tracker": "gnn", "gate_probability": 0.999}
    report = (tmp_path / "out" / "report.md").read_text()
    lines = report.splitlines()
    head = [c.strip() for c in next(line for line in lines if line.startswith("| method | reads |")).strip("|").split("|")]
    for name in ("Stone Soup JPDA", "Stone Soup GNN"):
        row = next(line for line in lines if line.startswith(f"| {name} | detections"))  # "(oracle births)"
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert float(cells[head.index("s / run")]) == pytest.approx(rows[name]["seconds_per_run"], abs=1e-3)
        timing = next(line for line in report.splitlines()
                      if line.startswith(f"| {name} |") and line.count("|") == 5)  # the run-time table
        assert float(timing.split("|")[2]) == pytest.approx(1e3 * rows[name]["seconds_per_run"], rel=1e-3, abs=0.01)
    assert "Stone Soup rows (Stone Soup JPDA, Stone Soup GNN): Stone Soup 1.9.1's EKF" in report
