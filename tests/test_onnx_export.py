"""ONNX export: the exported graph, run by onnxruntime, gives what ``pmsr track`` gives.

Tolerance: the graph computes in float32 (``pmsr track`` normalises in float64 and runs the
network in float32), so the two differ by float32 rounding of the normalised inputs and
outputs, ~1e-7 of a column's training span. We allow 1e-5 relative, with an absolute floor of
1e-5 of the column's span for values near zero (accelerations): 100x the rounding.
"""

from pathlib import Path

import h5py
import numpy as np
import onnx
import pytest
import torch

from pmsr_nn.cli import main
from pmsr_nn.data.sequences import write_csv_measurements
from pmsr_nn.nets.inference import Tracker
from pmsr_nn.nets.onnx_export import FIXES, INPUT, run_kalmannet_onnx, run_onnx

pytest.importorskip("onnxruntime")

ROOT = Path(__file__).resolve().parents[1]
RELEASED = ROOT / "models" / "released"


@pytest.fixture(scope="module")
def measurements(make_tracks):
    """Three noisy 240-scan tracks of the default recipe (the released trackers' geometry)."""
    _, _, batch = make_tracks(240, 3, 5)
    return batch.measurements.double()


def assert_parity(got, expected, span):
    """``|got - expected| <= 1e-5 |expected| + 1e-5 span`` elementwise (module docstring)."""
    excess = np.abs(got - expected) - 1e-5 * (np.abs(expected) + span)
    assert np.all(excess <= 0), f"worst excess {excess.max():.3g} at {np.unravel_index(excess.argmax(), excess.shape)}"


def _export(tmp_path, checkpoint):
    out = tmp_path / f"{checkpoint.stem}.onnx"
    assert main(["export-onnx", "--checkpoint", str(checkpoint), "--out", str(out)]) == 0
    return out


def _track(tmp_path, checkpoint, z):
    csv_in, est = tmp_path / "z.csv", tmp_path / "est.h5"
    tracker = Tracker.load(checkpoint)
    write_csv_measurements(csv_in, z, tracker.measurement_columns)
    assert main(["track", "--checkpoint", str(checkpoint), "--input", str(csv_in), "--out", str(est)]) == 0
    with h5py.File(est) as f:
        return tracker, f["estimates"][()]


@pytest.mark.parametrize("name, scans", [("mdfnn", 240), ("dfnn", 240), ("mdfnn_local_s0", 240), ("rnn", 100)])
def test_onnxruntime_matches_pmsr_track(tmp_path, measurements, name, scans):
    """Feedforward trackers on 240 scans (pmsr track splices windows of 100); the RNN on one window
    (beyond it pmsr track's spliced windows remember less than one pass does)."""
    checkpoint = RELEASED / f"{name}.pt"
    z = measurements[:, :scans]
    path = _export(tmp_path, checkpoint)
    tracker, expected = _track(tmp_path, checkpoint, z)
    feed = {INPUT: z}
    if tracker.representation.needs_fixes:
        feed[FIXES] = tracker.representation.fixes(z)
    got = run_onnx(path, feed)
    assert got.dtype == np.float32 and got.shape == expected.shape == (3, scans, 6)
    assert_parity(got, expected, tracker.state_scaler.span.numpy())


def test_a_longer_sequence_and_another_batch_size_run_through_the_dynamic_axes(tmp_path, measurements):
    path = _export(tmp_path, RELEASED / "mdfnn.pt")
    tracker = Tracker.load(RELEASED / "mdfnn.pt")
    for b, k in ((1, 240), (3, 57)):
        z = measurements[:b, :k]
        got = run_onnx(path, {INPUT: z})
        # One pass of the network (what pmsr track's splice equals for a feedforward tracker).
        with torch.no_grad():
            ref = tracker.state_scaler.denormalise(tracker.net(tracker.measurement_scaler.normalise(z).float()).double())
        assert_parity(got, ref.numpy(), tracker.state_scaler.span.numpy())


def test_the_model_names_its_axes_and_carries_its_columns_and_geometry(tmp_path):
    import json

    path = _export(tmp_path, RELEASED / "mdfnn.pt")
    model = onnx.load(str(path))
    meta = {p.key: p.value for p in model.metadata_props}
    tracker = Tracker.load(RELEASED / "mdfnn.pt")
    assert json.loads(meta["measurement_columns"]) == tracker.measurement_columns
    assert json.loads(meta["state_columns"]) == tracker.state_columns
    assert json.loads(meta["geometry"]) == tracker.meta["geometry"]
    assert json.loads(meta["window"]) == 100 and json.loads(meta["dt_s"]) == tracker.meta["dt_s"]
    assert json.loads(meta["context_scans"]) == {"behind": 38, "ahead": 0}
    (inp,), (out,) = model.graph.input, model.graph.output
    assert (inp.name, out.name) == ("measurements", "states")
    dims = [d.dim_param or d.dim_value for d in inp.type.tensor_type.shape.dim]
    assert dims == ["batch", "scans", 9]


@pytest.mark.parametrize("name", ["kalmannet_s0", "kalmannet_mismatch_s0"])
def test_a_kalmannet_step_graph_in_a_loop_is_as_exact_as_torch_float32(tmp_path, measurements, name):
    """The per-scan step graph run over one window of scans by run_kalmannet_onnx (the loop a
    deployment writes). Float32 rounding compounds through the recursion, so the reference is the
    network in float64: onnxruntime's float32 must be no further from it than torch's own float32
    run (pmsr track), with 2x and 1e-6 of a span to spare; and both agree to 1e-4 of a span (the
    export check's STEP_TOLERANCE)."""
    import copy

    checkpoint = RELEASED / f"{name}.pt"
    z = measurements[:, :100]
    path = _export(tmp_path, checkpoint)
    tracker, expected = _track(tmp_path, checkpoint, z)
    rep = tracker.representation
    got = run_kalmannet_onnx(path, z, rep.fixes(z))
    with torch.no_grad():
        exact = rep.states(copy.deepcopy(tracker.net).double()(rep.features(z)), rep.base(z)).numpy()
    span = tracker.state_scaler.span.numpy()
    assert got.shape == expected.shape == (3, 100, 6)
    ort_error = np.max(np.abs(got - exact) / span)
    torch_error = np.max(np.abs(expected - exact) / span)
    assert ort_error <= 2 * torch_error + 1e-6, (ort_error, torch_error)
    assert np.max(np.abs(got - expected) / span) <= 1e-4
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert meta["graph"] == "per_scan_step" and "state fix" in meta["loop"]


def test_an_unreadable_checkpoint_is_refused_and_nothing_is_written(tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    out = tmp_path / "t.onnx"
    code = main(["export-onnx", "--checkpoint", str(bad), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "bad.pt" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.pt"]
