"""The ``pmsr`` command.

Every user error (bad recipe, bad path, bad dataset) is a :class:`~pmsr_nn.errors.PmsrError`,
printed as one line ``pmsr: error: ...`` with exit code 2 and no traceback.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__
from .errors import PmsrError

DEMO_DIR = Path("runs/demo")


def _int_at_least(minimum: int, what: str):
    """An argparse type: an integer >= ``minimum`` with a one-line error otherwise."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected a {what} integer, got {text!r}")
        return value

    return parse


_positive_int = _int_at_least(1, "positive")
_nonneg_int = _int_at_least(0, "non-negative")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="pmsr",
        description="Target tracking in multistatic passive radar: simulate datasets, train and "
        "evaluate trackers. Run 'pmsr COMMAND --help' for the options of a command.",
    )
    p.add_argument("--version", action="version", version=f"pmsr_nn {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)

    s = sub.add_parser(
        "simulate",
        help="generate a track dataset from a recipe",
        description="Generate truth tracks and noisy bistatic measurements from a recipe (YAML) and "
        "write them atomically as a dataset directory (HDF5 + manifest.json). The same recipe and "
        "seed give byte-identical arrays.",
    )
    s.add_argument("recipe", type=Path, help="recipe YAML, e.g. datasets/fitee2023_ca.yaml")
    s.add_argument("--out", type=Path, required=True, help="dataset directory to create (must not exist unless --overwrite)")
    s.add_argument("--tracks", type=_positive_int, help="number of tracks (overrides the recipe's 'tracks')")
    s.add_argument("--seed", type=_nonneg_int, help="random seed (overrides the recipe's 'seed')")
    s.add_argument("--variant", choices=["envelope", "literal"],
                   help="'literal': the paper's recipe as written; 'envelope': tracks kept inside Table 1 (overrides the recipe)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing pmsr_nn dataset at --out")
    s.add_argument("--quiet", action="store_true", help="no progress bar and no summary")

    i = sub.add_parser("info", help="summarise a dataset", description="Print the summary of a dataset directory.")
    i.add_argument("path", type=Path, help="dataset directory")
    i.add_argument("--verify", action="store_true", help="also recompute and check every array checksum")
    i.add_argument("--plot", type=Path, metavar="PNG", help="also draw the sensors, the envelope and the first tracks")

    d = sub.add_parser(
        "demo",
        help="the main job on its built-in default",
        description="Simulate a small dataset of the built-in FITEE 2023 CA recipe in both variants "
        "(envelope and literal), write them under --out and print their summaries.",
    )
    d.add_argument("--out", type=Path, default=DEMO_DIR, help=f"output directory (default {DEMO_DIR})")
    d.add_argument("--tracks", type=_positive_int, help="tracks per dataset (default: the recipe's 70, the paper's scale)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return {"simulate": cmd_simulate, "info": cmd_info, "demo": cmd_demo}[args.command](args)
    except PmsrError as exc:
        print(f"pmsr: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pmsr: interrupted; nothing was left behind", file=sys.stderr)
        return 130


def cmd_simulate(args) -> int:
    from .data.store import write_dataset
    from .simulation.recipe import load_recipe

    recipe = load_recipe(args.recipe).with_overrides(tracks=args.tracks, seed=args.seed, variant=args.variant)
    t0 = time.perf_counter()
    manifest = write_dataset(recipe, args.out, overwrite=args.overwrite, progress=not args.quiet)
    seconds = time.perf_counter() - t0
    if not args.quiet:
        print(summarise(args.out, manifest, seconds))
    return 0


def cmd_info(args) -> int:
    from .data.store import open_dataset

    ds = open_dataset(args.path)
    if args.verify:
        ds.verify()
    print(summarise(args.path, ds.manifest))
    if args.verify:
        print("checksums: all arrays match the manifest")
    if args.plot:
        from .plots import plot_dataset_tracks

        print(f"figure    {plot_dataset_tracks(args.path, args.plot)}")
    return 0


def cmd_demo(args) -> int:
    from .data.store import is_our_dataset, write_dataset
    from .simulation.recipe import TrackRecipe

    from .plots import plot_dataset_tracks

    args.out.mkdir(parents=True, exist_ok=True)
    print("pmsr demo: the FITEE 2023 CA recipe (built-in defaults = datasets/fitee2023_ca.yaml), both variants\n")
    for variant in ("envelope", "literal"):
        out = args.out / f"fitee2023_ca_{variant}"
        recipe = TrackRecipe(variant=variant).with_overrides(tracks=args.tracks)
        t0 = time.perf_counter()
        manifest = write_dataset(recipe, out, overwrite=is_our_dataset(out))
        print(summarise(out, manifest, time.perf_counter() - t0))
        print(f"figure    {plot_dataset_tracks(out, args.out / f'tracks_{variant}.png')}")
        print()
    print("The learned trackers and the evaluation harness are not built yet; this demo stops at the dataset.")
    return 0


def summarise(path: Path, manifest: dict, seconds: float | None = None) -> str:
    """A human-readable summary of a dataset: sizes, splits, envelope statistics, motion percentiles."""
    from .data.store import open_dataset

    n, K, dx = manifest["shapes"]["states"]
    env = manifest["envelope"]
    lines = [
        f"dataset   {path}  ({manifest['name']}, variant '{manifest['variant']}', seed {manifest['seed']})",
        f"tracks    {n} x {K} samples (dt {manifest['dt_s']} s), state dim {dx}, measurement dim "
        f"{manifest['shapes']['measurements'][2]}, stored as {manifest['dtype']}",
        "splits    " + ", ".join(f"{k} {v} tracks / {manifest['windows'][k]} windows" for k, v in manifest["splits"].items())
        + f"  (window {manifest['window']}, {manifest['windows_per_track']} per track)",
        f"envelope  {env['fraction_left']:.1%} of tracks leave Table 1 ("
        + ", ".join(f"{k} {v:.1%}" for k, v in env["fraction_left_by_criterion"].items())
        + f"); acceptance of the draws {env['acceptance']:.1%}",
    ]
    ds = open_dataset(path)
    try:
        states = ds.file["states"][: min(n, 256)].astype(np.float64)
    finally:
        ds.close()
    dim = dx // 3
    pos = states[..., 0 : 3 * dim : 3]
    vel = states[..., 1 : 3 * dim : 3]
    origin = np.asarray(manifest["geometry"]["transmitters"][0]["position_m"][:dim])
    speed = np.linalg.norm(vel, axis=-1)
    dist = np.linalg.norm(pos[..., :2] - origin[:2], axis=-1)
    t100 = min(100, K - 1)
    lines.append(
        f"motion    median speed {np.median(speed[:, t100]):.1f} m/s and median distance "
        f"{np.median(dist[:, t100]) / 1e3:.2f} km from the transmitter at t = {t100 * manifest['dt_s']:.0f} s; "
        f"max speed {speed.max():.1f} m/s, max distance {dist.max() / 1e3:.1f} km (first {len(states)} tracks)"
    )
    if seconds is not None:
        lines.append(f"time      {seconds:.2f} s, {n * K / seconds / 1e6:.2f} M track-steps/s")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
