"""``pmsr simulate``: a track dataset from a recipe."""

from __future__ import annotations

import time
from pathlib import Path

from .common import nonneg_int, positive_int
from .info import summarise


def add_simulate(sub) -> None:
    s = sub.add_parser(
        "simulate",
        help="generate a track dataset from a recipe",
        description="Generate truth tracks and noisy bistatic measurements from a recipe (YAML) and "
        "write them atomically as a dataset directory (HDF5 + manifest.json). The same recipe and "
        "seed give byte-identical arrays.",
    )
    s.add_argument("recipe", type=Path, help="recipe YAML, e.g. datasets/fitee2023_ca.yaml")
    s.add_argument("--out", type=Path, required=True, help="dataset directory to create (must not exist unless --overwrite)")
    s.add_argument("--tracks", type=positive_int, help="number of tracks (overrides the recipe's 'tracks')")
    s.add_argument("--seed", type=nonneg_int, help="random seed (overrides the recipe's 'seed')")
    s.add_argument("--variant", choices=["envelope", "literal"],
                   help="'literal': the paper's recipe as written; 'envelope': tracks kept inside Table 1 (overrides the recipe)")
    s.add_argument("--no-splits", action="store_true",
                   help="put every track in the test split (for tracking and evaluation, not training); also what "
                        "happens, with a note, when the tracks are too few for the recipe's train/val/test split")
    s.add_argument("--overwrite", action="store_true", help="replace an existing pmsr_nn dataset at --out")
    s.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    s.set_defaults(run=cmd_simulate)


def cmd_simulate(args) -> int:
    from ..data.store import write_dataset
    from ..simulation.recipe import load_recipe_for_simulation

    recipe, why_unsplit = load_recipe_for_simulation(args.recipe, tracks=args.tracks, seed=args.seed,
                                                     variant=args.variant, no_splits=args.no_splits)
    t0 = time.perf_counter()
    manifest = write_dataset(recipe, args.out, overwrite=args.overwrite, progress=not args.quiet, inputs=[args.recipe])
    seconds = time.perf_counter() - t0
    if not args.quiet:
        print(summarise(args.out, manifest, seconds, why_unsplit=why_unsplit))
    return 0
