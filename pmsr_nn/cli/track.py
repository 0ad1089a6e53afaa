"""``pmsr track``: a trained tracker over measurement sequences (CSV or dataset) into an estimates file."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from .. import __version__
from ..errors import PmsrError
from .common import positive_int


def add_track(sub) -> None:
    tr = sub.add_parser(
        "track",
        help="estimate states from measurements with a trained tracker",
        description="Run a trained tracker over measurement sequences of any length (sliding windows, "
        "spliced). Input: a CSV with a header naming the checkpoint's measurement columns (SI units; an "
        "optional 'track' column holds several sequences), a dataset directory or its tracks.h5. Output: "
        ".csv (one estimate row per input row) or .h5.",
    )
    tr.add_argument("--checkpoint", type=Path, required=True, help="tracker.pt or a run's .ckpt")
    tr.add_argument("--input", type=Path, required=True, help="measurement CSV, dataset directory or its tracks.h5")
    tr.add_argument("--out", type=Path, required=True, help="estimates file, .csv or .h5")
    tr.add_argument("--split", choices=["train", "val", "test"], help="only this split of a dataset input")
    tr.add_argument("--stride", type=positive_int, help="window stride (default: the largest that keeps every estimate's full context)")
    tr.add_argument("--nan", choices=["error", "hold"], default="error",
                    help="a scan with a NaN: stop with an error (default) or repeat the last valid scan")
    tr.add_argument("--device", default="cpu", help="torch device (default cpu)")
    tr.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    tr.add_argument("--force", action="store_true",
                    help="track measurements that fail the plausibility checks (below a baseline, azimuth outside "
                         "[-pi, pi], far outside the training span)")
    tr.set_defaults(run=cmd_track)


def cmd_track(args) -> int:
    import torch

    from ..data.sequences import read_measurements, write_estimates
    from ..data.store import ARRAYS, is_our_dataset
    from ..environment import resolve_device
    from ..nets.inference import Tracker
    from ..outputs import check_file_target
    from ..plausibility import check_measurements

    inputs = [args.input, args.checkpoint]
    if args.input.name == ARRAYS and is_our_dataset(args.input.parent):
        inputs.append(args.input.parent)  # a dataset's tracks.h5: its folder is the input, as with --input DIR
    check_file_target(args.out, overwrite=args.overwrite, inputs=inputs, suffixes=(".csv", ".h5"))
    tracker = Tracker.load(args.checkpoint, device=resolve_device(args.device))
    if args.stride is not None and args.stride > tracker.window:
        raise PmsrError(f"--stride {args.stride} is longer than the network's window of {tracker.window} "
                        "samples: scans between windows would get no estimate")
    seqs = read_measurements(args.input, tracker.measurement_columns, split=args.split)
    if "geometry" in seqs.source:
        tracker.check_compatible(seqs.source["geometry"], seqs.source["columns"], seqs.source.get("dt_s"),
                                 where=f"dataset {args.input}")
    elif seqs.source.get("dt_s") is not None and abs(seqs.source["dt_s"] - tracker.meta["dt_s"]) > 1e-6 * tracker.meta["dt_s"]:
        raise PmsrError(f"{args.input}: time_s says the scans come every {seqs.source['dt_s']:g} s; the tracker was "
                        f"trained at {tracker.meta['dt_s']:g} s")
    if not args.force:
        span = (tracker.measurement_scaler.lo, tracker.measurement_scaler.hi)
        for i, z in enumerate(seqs.z):
            check_measurements(z, tracker.measurement_columns, tracker.geometry, span,
                               where=lambda b, k, i=i: f"{args.input}: track {seqs.track[i]!r}, row {int(seqs.rows[i][k]) + 1}")
    t0 = time.perf_counter()
    estimates: list = [None] * len(seqs.z)  # one (K, n) tensor per sequence
    for _, idx in seqs.by_length():
        batch = tracker.track(torch.stack([seqs.z[i] for i in idx]), stride=args.stride, nan=args.nan)
        for j, i in enumerate(idx):
            estimates[i] = batch[j]
    seconds = time.perf_counter() - t0
    write_estimates(args.out, seqs, estimates, tracker.state_columns,
                    {"checkpoint": str(args.checkpoint), "input": str(args.input), "pmsr_nn": __version__,
                     "model": tracker.meta["model"]["kind"], "looks_ahead": tracker.looks_ahead},
                    overwrite=args.overwrite, inputs=inputs)
    scans = sum(len(z) for z in seqs.z)
    kind = "smoother (looks ahead)" if tracker.looks_ahead else "causal filter"
    print(f"tracked   {len(seqs.z)} sequence(s), {scans} scans with {tracker.meta['model']['kind']} ({kind}) in "
          f"{seconds:.2f} s -> {args.out}")
    not_finite = sum(int((~torch.isfinite(x).all(-1)).sum()) for x in estimates)
    if not_finite:  # e.g. --force past the plausibility checks on values far outside the training span
        first = [(seqs.track[i], int(seqs.rows[i][int(k)]) + 1) for i, x in enumerate(estimates)
                 for k in torch.nonzero(~torch.isfinite(x).all(-1)).flatten()[:1]]
        print(f"warning   {not_finite} of {scans} estimates are not finite (NaN or inf), first at track {first[0][0]!r} "
              f"row {first[0][1]}: the input is outside what the network can track", file=sys.stderr)
    return 0
