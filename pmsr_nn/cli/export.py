"""``pmsr export`` (a dataset's measurements as CSV) and ``pmsr export-onnx`` (a trained tracker as ONNX)."""

from __future__ import annotations

import json
from pathlib import Path

from .common import positive_int


def add_export(sub) -> None:
    e = sub.add_parser("export", help="write a dataset's measurements as CSV",
                       description="Write the measurements of a dataset (all tracks or one split) as a CSV that "
                       "'pmsr track' reads: a 'track' column and the measurement columns in SI units.")
    e.add_argument("dataset", type=Path, help="dataset directory")
    e.add_argument("--out", type=Path, required=True, help="CSV file to write")
    e.add_argument("--split", choices=["train", "val", "test"], help="only this split")
    e.add_argument("--tracks", type=positive_int, help="at most this many tracks")
    e.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    e.set_defaults(run=cmd_export)


def add_export_onnx(sub) -> None:
    ox = sub.add_parser(
        "export-onnx",
        help="write a trained tracker as an ONNX model (onnxruntime checks it against pmsr track)",
        description="Write a DFNN / MDFNN / RNN tracker (tracker.pt or a run's .ckpt) as one ONNX graph: "
        "normalisation, network and read-out, float32, SI units in and out, named inputs 'measurements' "
        "(and 'state_fixes' for trackers that read fixes) and output 'states', dynamic batch and scan "
        "axes; columns, geometry, dt and window in the model's metadata. The graph is one pass over "
        "the sequence it is given (equal to 'pmsr track' for feedforward trackers; for an RNN on "
        "sequences of up to its window); a KalmanNet-style tracker is exported as its per-scan step, "
        "for a loop of your own. Needs the onnx extra: pip install \"pmsr-nn[onnx]\".",
    )
    ox.add_argument("--checkpoint", type=Path, required=True, help="tracker.pt or a run's .ckpt")
    ox.add_argument("--out", type=Path, required=True, help="ONNX file to write (.onnx)")
    ox.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    ox.set_defaults(run=cmd_export_onnx)


def cmd_export(args) -> int:
    import torch

    from ..data.sequences import read_dataset, write_csv_measurements
    from ..outputs import check_file_target

    check_file_target(args.out, overwrite=args.overwrite, inputs=[args.dataset], suffixes=(".csv",))
    seqs = read_dataset(args.dataset, args.split)
    z = torch.stack(seqs.z[: args.tracks] if args.tracks else seqs.z)  # (tracks, K, m)
    write_csv_measurements(args.out, z, seqs.source["columns"], overwrite=args.overwrite, inputs=[args.dataset])
    print(f"wrote     {len(z)} track(s) x {z.shape[1]} scans -> {args.out}")
    return 0


def cmd_export_onnx(args) -> int:
    from ..nets.inference import Tracker
    from ..nets.onnx_export import check_with_onnxruntime, export_onnx
    from ..outputs import atomic_file, check_file_target

    check_file_target(args.out, overwrite=args.overwrite, inputs=[args.checkpoint], suffixes=(".onnx",))
    tracker = Tracker.load(args.checkpoint)
    with atomic_file(args.out, overwrite=args.overwrite, inputs=[args.checkpoint], suffixes=(".onnx",)) as tmp:
        meta = export_onnx(tracker, tmp)
        check = check_with_onnxruntime(tracker, tmp)
    step = meta["graph"] == "per_scan_step"
    print(f"exported  {tracker.meta['model']['kind']} tracker -> {args.out}  ({args.out.stat().st_size / 1e6:.1f} MB; "
          + ("one scan per call, your loop around it (metadata 'loop'); dynamic batch axis)" if step else
             "dynamic batch and scan axes)"))
    print(f"graph     inputs {', '.join(json.loads(meta['inputs']))} -> outputs {', '.join(json.loads(meta['outputs']))}")
    if check is None:
        print("checked   not run: onnxruntime is not installed (pip install \"pmsr-nn[onnx]\")")
    else:
        print(f"checked   onnxruntime {check['onnxruntime']} against 'pmsr track' on {check['sequences']} sequences of "
              f"{check['scans']} scans: largest difference {check['max_diff_over_span']:.1e} of a state column's "
              "training span")
    return 0
