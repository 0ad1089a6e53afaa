"""``pmsr info``: the summary of a dataset (also printed by ``pmsr simulate``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def add_info(sub) -> None:
    i = sub.add_parser("info", help="summarise a dataset", description="Print the summary of a dataset directory.")
    i.add_argument("path", type=Path, help="dataset directory")
    i.add_argument("--verify", action="store_true", help="also recompute and check every array checksum")
    i.add_argument("--plot", type=Path, metavar="PNG", help="also draw the sensors, the envelope and the first tracks")
    i.add_argument("--overwrite", action="store_true", help="replace an existing --plot file")
    i.set_defaults(run=cmd_info)


def cmd_info(args) -> int:
    from ..data.store import open_dataset
    from ..outputs import atomic_file, check_file_target

    if args.plot:
        check_file_target(args.plot, overwrite=args.overwrite, inputs=[args.path], what="--plot", suffixes=(".png",))
    ds = open_dataset(args.path)
    try:
        if args.verify:
            ds.verify()
    finally:
        ds.close()
    print(summarise(args.path, ds.manifest))
    if args.verify:
        print("checksums: all arrays match the manifest")
    if args.plot:
        from ..plots import plot_dataset_tracks

        with atomic_file(args.plot, overwrite=args.overwrite, inputs=[args.path], what="--plot", suffixes=(".png",)) as tmp:
            plot_dataset_tracks(args.path, tmp)
        print(f"figure    {args.plot}")
    return 0


def summarise(path: Path, manifest: dict, seconds: float | None = None, why_unsplit: str | None = None) -> str:
    """A human-readable summary of a dataset: sizes, splits, envelope statistics, motion percentiles.
    ``seconds``: how long writing it took (adds a time line); ``why_unsplit``: why a dataset has no
    train/val split (appended to its splits line)."""
    from ..data.store import open_dataset

    n_tracks, K, n = manifest["shapes"]["states"]  # tracks, scans per track, state dimension
    env = manifest["envelope"]
    splits = manifest["splits"]
    if not splits.get("train") and not splits.get("val"):  # every track a test track (simulate --no-splits)
        split_line = (f"splits    none: all {splits.get('test', n_tracks)} tracks are test tracks, for tracking, not "
                      "training" + (f"; {why_unsplit}" if why_unsplit else ""))
    else:
        split_line = ("splits    " + ", ".join(f"{k} {v} tracks / {manifest['windows'].get(k, 0)} windows"
                                               for k, v in splits.items())
                      + f"  (window {manifest['window']}, {manifest['windows_per_track']} per track)")
    lines = [
        f"dataset   {path}  ({manifest['name']}, variant '{manifest['variant']}', seed {manifest['seed']})",
        f"tracks    {n_tracks} x {K} samples (dt {manifest['dt_s']} s), state dim {n}, measurement dim "
        f"{manifest['shapes']['measurements'][2]}, stored as {manifest['dtype']}",
        split_line,
        f"envelope  {env['fraction_left']:.1%} of tracks leave Table 1 ("
        + ", ".join(f"{k} {v:.1%}" for k, v in env["fraction_left_by_criterion"].items())
        + f"); acceptance of the draws {env['acceptance']:.1%}",
    ]
    ds = open_dataset(path)
    try:
        x = ds.file["states"][: min(n_tracks, 256)].astype(np.float64)  # (tracks, K, n)
    finally:
        ds.close()
    n_axes = n // 3  # position, velocity, acceleration per axis
    pos = x[..., 0 : 3 * n_axes : 3]
    vel = x[..., 1 : 3 * n_axes : 3]
    origin = np.asarray(manifest["geometry"]["transmitters"][0]["position_m"][:n_axes])
    speed = np.linalg.norm(vel, axis=-1)
    dist = np.linalg.norm(pos[..., :2] - origin[:2], axis=-1)
    k100 = min(100, K - 1)
    lines.append(
        f"motion    median speed {np.median(speed[:, k100]):.1f} m/s and median distance "
        f"{np.median(dist[:, k100]) / 1e3:.2f} km from the transmitter at t = {k100 * manifest['dt_s']:.0f} s; "
        f"max speed {speed.max():.1f} m/s, max distance {dist.max() / 1e3:.1f} km (first {len(x)} tracks)"
    )
    if seconds is not None:
        lines.append(f"time      {seconds:.2f} s, {n_tracks * K / seconds / 1e6:.2f} M track-steps/s")
    return "\n".join(lines)
