"""Benchmark: a released tracker exported to ONNX and run by onnxruntime, beside the same network in torch.

For each checkpoint (``--checkpoints``, names under ``models/released/``): export it with
``pmsr_nn.nets.onnx_export.export_onnx`` into a temporary folder, then track ``--batch`` noisy
sequences of ``--scans`` scans (the default recipe's geometry, ``example_inputs``) both ways on the
CPU, in this process, one after the other (the same threads: ``--threads``, default torch's):

* ``torch``: what the graph computes, in torch, float32, without autograd: the
  :class:`~pmsr_nn.nets.onnx_export.ExportGraph` module (normalisation, network, read-out), or the
  KalmanNet step module in the same loop as ``run_kalmannet_onnx``;
* ``onnxruntime``: the exported file in an ``InferenceSession`` (CPU provider), same inputs.

Each is the median of ``--repeats`` calls after one untimed warm-up; reported as scans per second
(``batch x scans / seconds``) and the ratio onnxruntime / torch, with the largest difference between
the two outputs in units of a state column's training span.

    python benchmarks/bench_onnx.py --json benchmarks/results/bench_onnx.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import torch

from pmsr_nn.environment import environment
from pmsr_nn.nets.inference import Tracker
from pmsr_nn.nets.onnx_export import (OUTPUT, STEP_INPUTS, STEP_OUTPUTS, ExportGraph, KalmanNetStepGraph,
                                      example_inputs, export_onnx, graph_inputs)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import median_seconds  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def bench_one(name: str, batch: int, scans: int, repeats: int, tmp: Path) -> dict:
    import onnxruntime

    tracker = Tracker.load(ROOT / "models" / "released" / f"{name}.pt")
    path = tmp / f"{name}.onnx"
    export_onnx(tracker, path)
    z, *fixes = example_inputs(tracker, batch=batch, scans=scans, seed=2)
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    if tracker.model.kind == "kalmannet":
        step = KalmanNetStepGraph(tracker)
        zf, x0 = z.float(), fixes[0][:, 0].float()

        def loop(run_step):
            x = x_prev = x_pred = x0
            hidden = torch.zeros(batch, step.hidden_size)
            out = [x]
            for k in range(1, scans):
                x_new, x_pred, hidden = run_step(zf[:, k], zf[:, k - 1], x, x_prev, x_pred, hidden)
                x_prev, x = x, x_new
                out.append(x)
            return torch.stack(out, 1)

        def ort_step(*args):
            outs = session.run(list(STEP_OUTPUTS), dict(zip(STEP_INPUTS, (a.numpy() for a in args))))
            return tuple(torch.from_numpy(o) for o in outs)

        with torch.no_grad():
            run_torch = lambda: loop(step)  # noqa: E731
            run_ort = lambda: loop(ort_step)  # noqa: E731
            ref, got = run_torch(), run_ort()
            t_torch, t_ort = median_seconds(run_torch, repeats), median_seconds(run_ort, repeats)
    else:
        graph = ExportGraph(tracker)
        args = tuple(a.float() for a in graph_inputs(graph, z, *fixes))
        feed = {n: a.numpy() for n, a in zip(graph.input_names, args)}
        with torch.no_grad():
            run_torch = lambda: graph(*args)  # noqa: E731
            run_ort = lambda: session.run([OUTPUT], feed)[0]  # noqa: E731
            ref, got = run_torch(), torch.from_numpy(run_ort())
            t_torch, t_ort = median_seconds(run_torch, repeats), median_seconds(run_ort, repeats)
    span = tracker.state_scaler.span.float()
    steps = batch * scans
    row = {"checkpoint": name, "kind": tracker.model.kind, "batch": batch, "scans": scans,
           "torch_scans_per_s": steps / t_torch, "onnxruntime_scans_per_s": steps / t_ort,
           "onnxruntime_over_torch": t_torch / t_ort,
           "max_diff_over_span": float(((got - ref).abs() / span).max()), "file_mb": path.stat().st_size / 1e6}
    print(f"{name:16s} {tracker.model.kind:9s} torch {row['torch_scans_per_s']:12,.0f} scans/s   onnxruntime "
          f"{row['onnxruntime_scans_per_s']:12,.0f} scans/s   ratio {row['onnxruntime_over_torch']:5.2f}   "
          f"max diff {row['max_diff_over_span']:.1e} of span", flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoints", nargs="+", default=["dfnn", "mdfnn", "rnn", "mdfnn_local_s0", "kalmannet_s0"])
    ap.add_argument("--batch", type=int, default=64, help="sequences per call (default 64)")
    ap.add_argument("--scans", type=int, default=100, help="scans per sequence (default 100, one training window)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, help="torch and onnxruntime intra-op threads (default: torch's)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    import onnxruntime

    print(f"onnxruntime {onnxruntime.__version__}, torch {torch.__version__}, {torch.get_num_threads()} threads; "
          f"{args.batch} sequences x {args.scans} scans per call, median of {args.repeats}")
    with tempfile.TemporaryDirectory() as tmp:
        rows = [bench_one(n, args.batch, args.scans, args.repeats, Path(tmp)) for n in args.checkpoints]
    if args.json:
        args.json.write_text(json.dumps({"environment": environment(), "onnxruntime": onnxruntime.__version__,
                                         "rows": rows}, indent=1) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
