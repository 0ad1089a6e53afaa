"""``pmsr front-end``: the FM front end (cancellation, 2D-CCF, OS-CFAR, centroiding) on recorded I/Q samples."""

from __future__ import annotations

import time
from pathlib import Path


def add_front_end(sub) -> None:
    fe = sub.add_parser(
        "front-end", help="run the FM front end on recorded I/Q samples",
        description="Cancellation, 2D-CCF, OS-CFAR and centroiding of every CPI of an HDF5 recording (complex "
        "datasets 'ref' and 'surv', attribute sample_rate_hz) with the settings of a front_end YAML (or a scenario "
        "with a detections.front_end block); write OUT/maps.h5 and OUT/detections.csv.")
    fe.add_argument("recording", type=Path, help="HDF5 file with 'ref' and 'surv' (samples,) or (cpis, samples)")
    fe.add_argument("--settings", type=Path, required=True, help="front_end YAML, e.g. evaluate/fm_front_end.yaml")
    fe.add_argument("--out", type=Path, required=True, help="output folder (new or empty unless --overwrite)")
    fe.add_argument("--overwrite", action="store_true", help="replace a folder an earlier front-end run wrote")
    fe.set_defaults(run=cmd_front_end)


def cmd_front_end(args) -> int:
    from ..frontend.recording import process_recording

    t0 = time.perf_counter()
    s = process_recording(args.recording, args.settings, args.out, overwrite=args.overwrite)
    print(f"front end {s['cpis']} CPIs -> {s['detections']} detections on {s['map'][0]} x {s['map'][1]} (Doppler x "
          f"range) maps, cancellation {s['cancellation_depth_db']:.1f} dB, {time.perf_counter() - t0:.1f} s -> "
          f"{args.out / 'detections.csv'}, {args.out / 'maps.h5'}")
    return 0
