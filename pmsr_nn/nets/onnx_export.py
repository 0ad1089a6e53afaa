"""ONNX export of a trained tracker: normalisation, network and read-out as one graph.

The graph maps measurements to states in SI units, float32, for any number of sequences and
scans (dynamic axes ``batch`` and ``scans``)::

    measurements (batch, scans, dim_z)  ->  states (batch, scans, dim_x)        inputs: measurements
    state_fixes  (batch, scans, dim_x)  ->  states (batch, scans, dim_x)        inputs: local_fixes
    measurements, state_fixes           ->  states                             measurements, output: residual

It is one pass of the network over the whole sequence it is given. For a feedforward tracker
(DFNN, MDFNN) that is exactly what ``pmsr track`` computes (its sliding windows keep every
estimate's full context, :mod:`pmsr_nn.nets.inference`); a recurrent tracker (RNN) run over a
sequence longer than its training window remembers more than ``pmsr track``'s spliced windows
do, so the two agree on sequences of up to ``window`` scans.

Representations that read state fixes (``inputs: local_fixes`` or ``output: residual``) take
the fixes as an input, ``state_fixes``: computing them is a spherical-interpolation solve
with Gauss-Newton steps and conditioning checks (eigenvalues), which ONNX has no operators
for. They come from :func:`pmsr_nn.filters.fixes.state_fixes` with missing ones held
(:meth:`~pmsr_nn.nets.representation.Representation.fixes`).

The KalmanNet-style tracker is a loop over scans around a learned gain; it is exported as its
per-scan step (:class:`KalmanNetStepGraph`, dynamic batch axis), which the deployment runs in its
own loop, started at the first scan's state fix (:func:`run_kalmannet_onnx` is that loop).

The model's metadata (``metadata_props``) carry what a user of the file needs: the measurement
and state columns, the sensor geometry, the sampling interval, the training window, the
context and the package version, as JSON strings.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import nn

from .. import __version__
from ..errors import CheckpointError, ConfigError
from .inference import Tracker

OPSET = 18
INPUT = "measurements"
FIXES = "state_fixes"
OUTPUT = "states"


def _require_onnx():
    try:
        import onnx  # noqa: F401
    except ImportError as exc:
        raise ConfigError(f"ONNX export needs the onnx extra ({exc.name} is missing): "
                          'pip install "pmsr-nn[onnx]"') from None


class ExportGraph(nn.Module):
    """``(measurements [, state_fixes]) -> states``, float32, SI units (module docstring).

    The same arithmetic as :meth:`Tracker.track` (:class:`~pmsr_nn.nets.representation.Representation`),
    written with the operators ONNX has; checked against it in the tests."""

    def __init__(self, tracker: Tracker):
        super().__init__()
        rep = tracker.representation
        self.net = tracker.net.float().eval()
        self.inputs, self.output = rep.inputs, rep.output
        self.uses_fixes = rep.needs_fixes
        f32 = torch.float32
        self.register_buffer("z_lo", rep.z_scaler.lo.to(f32))
        self.register_buffer("z_span", rep.z_scaler.span.to(f32))
        self.register_buffer("x_lo", rep.x_scaler.lo.to(f32))
        self.register_buffer("x_span", rep.x_scaler.span.to(f32))
        if self.inputs not in ("measurements", "local_fixes"):
            raise CheckpointError(f"{tracker.source}: inputs {self.inputs!r} are not supported by the ONNX export")
        if self.inputs == "local_fixes":
            self.register_buffer("f_mean", rep.feature_mean.to(f32))
            self.register_buffer("f_std", rep.feature_std.to(f32))
            self.pos_idx, self.vel_idx = list(rep.model.pos_idx), list(rep.model.vel_idx)
        if self.output == "residual":
            self.register_buffer("x_scale", rep.residual_scale.to(f32))

    @property
    def input_names(self) -> list[str]:
        """What the graph reads: the measurements, the state fixes, or both."""
        return ([INPUT] if self.inputs == "measurements" else []) + ([FIXES] if self.uses_fixes else [])

    def forward(self, *tensors: torch.Tensor) -> torch.Tensor:
        named = dict(zip(self.input_names, tensors))
        z, fixes = named.get(INPUT), named.get(FIXES)
        if self.inputs == "measurements":
            u = 2.0 * (z - self.z_lo) / self.z_span - 1.0
        else:
            pos = fixes[..., self.pos_idx]
            inc = pos - torch.cat([pos[:, :1], pos[:, :-1]], 1)  # 0 at the sequence start
            u = (torch.cat([inc, fixes[..., self.vel_idx], pos], -1) - self.f_mean) / self.f_std
        y = self.net(u)
        if self.output == "residual":
            return fixes + self.x_scale * y
        return (y + 1.0) * 0.5 * self.x_span + self.x_lo


STEP_INPUTS = ("measurements", "previous_measurements", "previous_state", "state_before_previous",
               "previous_prediction", "previous_hidden")
STEP_OUTPUTS = ("state", "prediction", "hidden")


class KalmanNetStepGraph(nn.Module):
    """One scan of a KalmanNet-style tracker (:meth:`KalmanNetTracker.step`), float32, SI units:
    ``(z_k, z_{k-1}, x_{k-1}, x_{k-2}, x_pred_{k-1}, h_{k-1}) -> (x_k, x_pred_k, h_k)``, each
    ``(batch, columns)`` (``h``: the GRU state, ``(batch, hidden)``)."""

    def __init__(self, tracker: Tracker):
        super().__init__()
        self.net = tracker.net.float().eval()

    @property
    def hidden_size(self) -> int:
        return self.net.gru.hidden_size

    def forward(self, z, z_prev, x, x_prev, x_pred_prev, hidden):
        return self.net.step(z, z_prev, x, x_prev, x_pred_prev, hidden)


def run_kalmannet_onnx(path: Path, z: torch.Tensor, fixes: torch.Tensor):
    """States ``(B, K, n)`` (float32 NumPy) of an exported KalmanNet step graph run by onnxruntime
    over measurements ``z (B, K, m)`` (SI) with their state fixes ``(B, K, n)``: the loop a
    deployment writes (the filter starts at the first scan's fix, GRU state zero)."""
    import numpy as np
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    hidden_size = session.get_inputs()[STEP_INPUTS.index("previous_hidden")].shape[1]
    z = z.float().numpy()
    x = x_prev = x_pred = fixes[:, 0].float().numpy()
    hidden = np.zeros((z.shape[0], hidden_size), dtype=np.float32)
    out = [x]
    for k in range(1, z.shape[1]):
        x_new, x_pred, hidden = session.run(list(STEP_OUTPUTS), dict(zip(STEP_INPUTS, (z[:, k], z[:, k - 1], x, x_prev,
                                                                                      x_pred, hidden))))
        x_prev, x = x, x_new
        out.append(x)
    return np.stack(out, 1)


def export_metadata(tracker: Tracker, names: list[str]) -> dict[str, str]:
    """``metadata_props`` of the exported model: JSON strings (module docstring)."""
    meta = tracker.meta
    behind, ahead = tracker.context
    return {
        "pmsr_nn_version": __version__,
        "model_kind": tracker.model.kind,
        "inputs": json.dumps(names),
        "measurement_columns": json.dumps(tracker.measurement_columns),
        "state_columns": json.dumps(tracker.state_columns),
        "units": "SI: m, m/s, m/s^2, rad",
        "geometry": json.dumps(meta["geometry"]),
        "dt_s": json.dumps(meta["dt_s"]),
        "window": json.dumps(tracker.window),
        "context_scans": json.dumps({"behind": behind, "ahead": ahead}),
        "looks_ahead": json.dumps(tracker.looks_ahead),
        "state_fixes": "pmsr_nn.nets.representation.Representation.fixes" if FIXES in names else "",
        "source_checkpoint": Path(tracker.source).name,
    }


def graph_inputs(graph: ExportGraph, z: torch.Tensor, fixes: torch.Tensor | None = None) -> tuple[torch.Tensor, ...]:
    """The tensors the graph reads, in its input order, of measurements ``z`` and their fixes."""
    return tuple({INPUT: z, FIXES: fixes}[n] for n in graph.input_names)


def example_inputs(tracker: Tracker, batch: int = 2, scans: int | None = None, seed: int = 0):
    """Plausible inputs ``(z (B, K, m) float64 SI [, fixes (B, K, n)])``: per sequence a
    constant-velocity path (the package's CA motion model, acceleration zero) started at a state
    drawn uniformly over the middle half of the training states' range, its measurement rows with
    noise of 1e-4 of the measurements' span (exported with them; the CLI's check runs on them)."""
    from ..motion import ConstantAcceleration
    from .representation import measurement_model

    g = torch.Generator().manual_seed(seed)
    K = scans or tracker.window
    lo, span = tracker.state_scaler.lo, tracker.state_scaler.span
    model = measurement_model(tracker.meta["geometry"], tracker.measurement_columns, tracker.meta["dim_x"])
    x0 = lo + span * (0.25 + 0.5 * torch.rand(batch, len(lo), generator=g, dtype=torch.float64))
    x0[:, [i for i in range(len(lo)) if i not in (*model.pos_idx, *model.vel_idx)]] = 0.0  # accelerations
    t = torch.arange(K, dtype=torch.float64) * tracker.meta["dt_s"]
    F = ConstantAcceleration(spatial_dim=len(lo) // 3).F(t)  # (K, n, n): scan 0 to each scan
    x = torch.einsum("kij,bj->bki", F, x0)  # (B, K, n)
    z = model.h(x)
    z = z + 1e-4 * tracker.measurement_scaler.span * torch.randn(z.shape, generator=g, dtype=torch.float64)
    rep = tracker.representation
    return (z, rep.fixes(z)) if rep.needs_fixes else (z,)


def export_onnx(tracker: Tracker, out: Path, opset: int = OPSET) -> dict[str, str]:
    """Write ``tracker`` as an ONNX model at ``out`` (a path the caller owns); returns its metadata."""
    _require_onnx()
    import logging
    import warnings

    import onnx

    if tracker.model.kind == "kalmannet":
        graph = KalmanNetStepGraph(tracker)
        names, outputs = list(STEP_INPUTS), list(STEP_OUTPUTS)
        z, fixes = (a.float() for a in example_inputs(tracker, scans=3))
        x = fixes[:, 1]
        args = (z[:, 2], z[:, 1], x, fixes[:, 0], x, torch.zeros(len(z), graph.hidden_size, dtype=torch.float32))
        axes = {n: {0: "batch"} for n in [*names, *outputs]}
        shapes = "(batch, columns) per scan"
    else:
        graph = ExportGraph(tracker)
        names, outputs = graph.input_names, [OUTPUT]
        args = tuple(a.float() for a in graph_inputs(graph, *example_inputs(tracker)))
        axes = {n: {0: "batch", 1: "scans"} for n in [*names, *outputs]}
        shapes = "(batch, scans, columns)"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        level = logging.getLogger("torch.onnx").level
        logging.getLogger("torch.onnx").setLevel(logging.ERROR)
        try:
            # The TorchScript exporter: torch.export (dynamo=True) cannot yet trace the recurrent
            # layers or the fix features with symbolic batch and scan sizes (torch 2.13).
            torch.onnx.export(graph, args, str(out), input_names=names, output_names=outputs,
                              dynamic_axes=axes, opset_version=opset, dynamo=False)
        finally:
            logging.getLogger("torch.onnx").setLevel(level)
    proto = onnx.load(str(out))
    meta = export_metadata(tracker, names)
    meta["outputs"] = json.dumps(outputs)
    meta["graph"] = "per_scan_step" if tracker.model.kind == "kalmannet" else "whole_sequence"
    if meta["graph"] == "per_scan_step":
        meta["state_fixes"] = "pmsr_nn.nets.representation.Representation.fixes"
        meta["loop"] = ("scan 0: state = the scan's state fix; then per scan k >= 1: (measurements z_k, previous_measurements "
                        "z_{k-1}, previous_state x_{k-1}, state_before_previous x_{k-2}, previous_prediction, previous_hidden) "
                        "-> (state x_k, prediction, hidden); at k = 1, x_{k-2} and the previous prediction are x_0 and "
                        "the hidden state is zero (pmsr_nn.nets.onnx_export.run_kalmannet_onnx)")
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.producer_name, proto.producer_version = "pmsr_nn", __version__
    proto.doc_string = (f"{tracker.model.kind} tracker: {', '.join(names)} -> {', '.join(outputs)}, {shapes}, SI units, "
                        "float32; columns in metadata_props (pmsr_nn.nets.onnx_export)")
    onnx.checker.check_model(proto)
    onnx.save(proto, str(out))
    return meta


def run_onnx(path: Path, feed: dict[str, torch.Tensor]):
    """States ``(B, K, n)`` (float32 NumPy) of the ONNX model at ``path`` run by onnxruntime on
    ``feed`` (input name -> tensor; the names the model does not read are ignored)."""
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    wanted = {i.name for i in session.get_inputs()}
    return session.run([OUTPUT], {k: v.float().numpy() for k, v in feed.items() if k in wanted})[0]


STEP_TOLERANCE = 1e-4
"""The check's tolerance for a per-scan step graph: float32 rounding compounds through the filter
recursion (torch's own float32 run of a released KalmanNet differs from float64 by 3e-5 of the
acceleration column's span over 64 x 100 scans, benchmarks/bench_onnx.py's inputs); a wrong graph
is off by order 1."""


def check_with_onnxruntime(tracker: Tracker, path: Path, batch: int = 4, tolerance: float = 1e-5) -> dict | None:
    """Run the exported model with onnxruntime beside :meth:`Tracker.track` on example inputs of
    one training window; None when onnxruntime is not installed. A difference beyond
    ``tolerance`` times a state column's training span (float32 arithmetic is ~1e-7; a step graph
    gets :data:`STEP_TOLERANCE`) is an error."""
    try:
        import onnxruntime
    except ImportError:
        return None
    ins = example_inputs(tracker, batch=batch, seed=1)
    if tracker.model.kind == "kalmannet":
        tolerance = max(tolerance, STEP_TOLERANCE)
        got = torch.from_numpy(run_kalmannet_onnx(path, *ins)).double()
    else:
        got = torch.from_numpy(run_onnx(path, dict(zip([INPUT, FIXES], ins)))).double()
    ref = tracker.track(ins[0])
    worst = float(((got - ref).abs() / tracker.state_scaler.span).max())
    if not worst <= tolerance:  # NaN fails too
        raise CheckpointError(f"the exported graph differs from 'pmsr track' by {worst:.1e} of a state column's "
                              f"span (tolerance {tolerance:g}); please report this")
    return {"onnxruntime": onnxruntime.__version__, "sequences": batch, "scans": tracker.window,
            "max_diff_over_span": worst}
