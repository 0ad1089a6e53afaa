"""The ``pmsr`` command.

One error path for every command: an anticipated failure (a bad recipe, path, dataset,
checkpoint or device; a file that cannot be read or written; memory) is printed as one line
``pmsr: error: ...`` naming the file, key or argument at fault, exit code 2. An unexpected
exception (a bug) prints one line with a hint, exit code 1; ``--debug`` shows its traceback.
SIGINT, SIGTERM and SIGHUP stop a command cleanly (no half-written output), with one line and
exit code ``128 + signal``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__
from .errors import ConfigError, Interrupted, PmsrError

DEMO_EXPECTED = "about 2.5 min on 2 CPU cores"
"""What the header promises: ``pmsr demo`` took 2.6 min on this project's 2-core Intel Xeon (AVX512),
2026-11-26, beside other jobs (the stage times in ``harness.demo.REFERENCE_SECONDS``); each stage's bar
shows its own time left as it runs."""

DEMO_DIR = Path("runs/demo")


def _int_at_least(minimum: int, what: str, maximum: int | None = None):
    """An argparse type: an integer in ``[minimum, maximum]`` with a one-line error otherwise."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected a {what} integer, got {text!r}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"at most {maximum:,}, got {value:,}")
        return value

    return parse


_positive_int = _int_at_least(1, "positive")
_nonneg_int = _int_at_least(0, "non-negative")
_mc_runs = _int_at_least(1, "positive", maximum=10_000_000)  # MAX_MC_RUNS of the scenarios


class _Parser(argparse.ArgumentParser):
    """argparse with its errors as one ``pmsr: error:`` line, like every other error of the command."""

    def error(self, message: str):
        self.exit(2, f"pmsr: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="pmsr",
        description="Target tracking in multistatic passive radar: simulate datasets, train and "
        "evaluate trackers. Run 'pmsr COMMAND --help' for the options of a command.",
    )
    p.add_argument("--version", action="version", version=f"pmsr_nn {__version__}")
    p.add_argument("--debug", action="store_true", help="show the traceback of an unexpected error")
    common = _Parser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show the traceback of an unexpected error")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    _add_parser = sub.add_parser
    sub.add_parser = lambda *a, **k: _add_parser(*a, parents=[common], **k)  # --debug after the command too

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
    s.add_argument("--no-splits", action="store_true",
                   help="put every track in the test split (for tracking and evaluation, not training); also what "
                        "happens, with a note, when the tracks are too few for the recipe's train/val/test split")
    s.add_argument("--overwrite", action="store_true", help="replace an existing pmsr_nn dataset at --out")
    s.add_argument("--quiet", action="store_true", help="no progress bar and no summary")

    i = sub.add_parser("info", help="summarise a dataset", description="Print the summary of a dataset directory.")
    i.add_argument("path", type=Path, help="dataset directory")
    i.add_argument("--verify", action="store_true", help="also recompute and check every array checksum")
    i.add_argument("--plot", type=Path, metavar="PNG", help="also draw the sensors, the envelope and the first tracks")
    i.add_argument("--overwrite", action="store_true", help="replace an existing --plot file")

    t = sub.add_parser(
        "train",
        help="train a learned tracker (DFNN / MDFNN / RNN)",
        description="Train a tracker from a YAML config (train/*.yaml) into a run folder: checkpoints "
        "(best and last), TensorBoard logs (RUN/tb), the resolved config, tracker.pt for inference and "
        "metrics.json. KEY=VALUE overrides change any config entry, e.g. trainer.max_epochs=5 "
        "model.filter_order=10. A missing dataset is simulated once into the config's cache_dir.",
    )
    t.add_argument("config", nargs="?", help="training config YAML (optional with --resume)")
    t.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides (YAML values)")
    t.add_argument("--out", type=Path, required=True, help="run folder (new, or the run to --resume)")
    t.add_argument("--resume", action="store_true", help="continue an interrupted run from RUN/checkpoints/last.ckpt")
    t.add_argument("--verbose", action="store_true",
                   help="Lightning's own progress bars, model summary and messages instead of one line per epoch")

    sel = sub.add_parser(
        "select",
        help="train u models and keep the best (Section 3.3 of the MDFNN paper)",
        description="Train --members models of one config with different seeds and cross-validation folds "
        "of the train+val tracks, evaluate each on its validation fold and on fresh tracks never used in "
        "training, keep the best (lowest fresh-track position RMSE) as OUT/best.pt and write the "
        "comparison table OUT/selection.md and OUT/selection.json.",
    )
    sel.add_argument("config", help="training config YAML")
    sel.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides (YAML values)")
    sel.add_argument("--out", type=Path, required=True, help="output folder (must not exist)")
    sel.add_argument("--members", type=_positive_int, default=10, help="number of models u (default 10, the paper's)")
    sel.add_argument("--fresh-tracks", type=_positive_int, default=20, help="fresh evaluation tracks (default 20)")

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
    tr.add_argument("--stride", type=_positive_int, help="window stride (default: the largest that keeps every estimate's full context)")
    tr.add_argument("--nan", choices=["error", "hold"], default="error",
                    help="a scan with a NaN: stop with an error (default) or repeat the last valid scan")
    tr.add_argument("--device", default="cpu", help="torch device (default cpu)")
    tr.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    tr.add_argument("--force", action="store_true",
                    help="track measurements that fail the plausibility checks (below a baseline, azimuth outside "
                         "[-pi, pi], far outside the training span)")

    e = sub.add_parser("export", help="write a dataset's measurements as CSV",
                       description="Write the measurements of a dataset (all tracks or one split) as a CSV that "
                       "'pmsr track' reads: a 'track' column and the measurement columns in SI units.")
    e.add_argument("dataset", type=Path, help="dataset directory")
    e.add_argument("--out", type=Path, required=True, help="CSV file to write")
    e.add_argument("--split", choices=["train", "val", "test"], help="only this split")
    e.add_argument("--tracks", type=_positive_int, help="at most this many tracks")
    e.add_argument("--overwrite", action="store_true", help="replace an existing --out file")

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

    ev = sub.add_parser(
        "evaluate",
        help="run every method of a scenario on the same Monte Carlo draws",
        description="Run a scenario (evaluate/*.yaml): every method on the same truth and measurement draws, "
        "the PCRB of each case; write OUT/results.json, OUT/report.md and PNG figures. With --shard I/N only a "
        "slice of the Monte Carlo runs is run and OUT holds shard.json + blocks.npz for 'pmsr merge'.",
    )
    ev.add_argument("scenario", type=Path, help="scenario YAML, e.g. evaluate/fitee2023_three_trajectories.yaml")
    ev.add_argument("--out", type=Path, required=True, help="output folder (new or empty unless --overwrite)")
    ev.add_argument("--mc-runs", type=_mc_runs, help="Monte Carlo runs per case (overrides the scenario's)")
    ev.add_argument("--checkpoint", action="append", default=[], metavar="NAME=PATH",
                    help="use this checkpoint for learned method NAME (repeatable)")
    ev.add_argument("--shard", default="1/1", metavar="I/N", help="run the I-th of N slices of the runs (default 1/1: all)")
    ev.add_argument("--device", default="cpu", help="torch device for the learned trackers (default cpu)")
    ev.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    ev.add_argument("--quiet", action="store_true", help="no progress bar and no table")
    ev.add_argument("--executor", choices=("local", "slurm"),
                    help="run the scenario as --shards jobs of submitit on this machine (local) or a SLURM array "
                    "(slurm), then merge them into --out")
    ev.add_argument("--shards", type=int, default=2, help="jobs for --executor (default 2; at most the blocks of runs)")
    ev.add_argument("--partition", help="SLURM partition for --executor slurm")
    ev.add_argument("--timeout-min", type=int, default=60, help="time limit per shard job for --executor (default 60)")

    fe = sub.add_parser(
        "front-end", help="run the FM front end on recorded I/Q samples",
        description="Cancellation, 2D-CCF, OS-CFAR and centroiding of every CPI of an HDF5 recording (complex "
        "datasets 'ref' and 'surv', attribute sample_rate_hz) with the settings of a front_end YAML (or a scenario "
        "with a front_end block); write OUT/maps.h5 and OUT/detections.csv.")
    fe.add_argument("recording", type=Path, help="HDF5 file with 'ref' and 'surv' (samples,) or (cpis, samples)")
    fe.add_argument("--settings", type=Path, required=True, help="front_end YAML, e.g. evaluate/fm_front_end.yaml")
    fe.add_argument("--out", type=Path, required=True, help="output folder (new or empty unless --overwrite)")
    fe.add_argument("--overwrite", action="store_true", help="replace a folder an earlier front-end run wrote")

    me = sub.add_parser("methods", help="list the method kinds a scenario can run, with their options",
                        description="Each method kind of a scenario's 'methods:' list: the product it reads, what it is, "
                        "its options with default and range; and where the trackers that are not method kinds live.")
    me.add_argument("kinds", nargs="*", help="only these kinds (default: all)")

    mg = sub.add_parser("merge", help="combine the shards of a scenario run",
                        description="Combine the output folders of 'pmsr evaluate --shard I/N' runs (all N of them) "
                        "into the results, report and figures of the whole run.")
    mg.add_argument("shards", type=Path, nargs="+", help="shard output folders")
    mg.add_argument("--out", type=Path, required=True, help="output folder")
    mg.add_argument("--overwrite", action="store_true", help="replace an existing output folder")

    d = sub.add_parser(
        "demo",
        help=f"the main job on its built-in default ({DEMO_EXPECTED})",
        description="Simulate a small dataset of the built-in FITEE 2023 CA recipe, train a small MDFNN and a "
        "small KalmanNet-style filter on it, evaluate them against the EKF, UKF, SI+KF and the PCRB on the three "
        "built-in trajectories, then run a small version of the flagship scenario evaluate/one_sky.yaml (four "
        "drones, 2 transmitters x 3 receivers: single-target filters, a released network, the PCRB and S-MSJPDA on "
        "detections); print both tables and write the reports (OUT/evaluation/, OUT/one_sky/). "
        f"It takes {DEMO_EXPECTED}.",
    )
    d.add_argument("--out", type=Path, default=DEMO_DIR, help=f"output folder (default {DEMO_DIR}; a previous demo there is replaced)")
    d.add_argument("--mc-runs", type=_mc_runs, default=20, help="Monte Carlo runs per trajectory (default 20)")
    d.add_argument("--verbose", action="store_true", help="Lightning's own progress bars and messages while training")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:  # KEY=VALUE overrides may follow options (argparse stops collecting positionals there)
        if hasattr(args, "overrides") and all("=" in e and not e.startswith("-") for e in extra):
            args.overrides = [*args.overrides, *extra]
        else:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
    commands = {"simulate": cmd_simulate, "info": cmd_info, "train": cmd_train, "select": cmd_select,
                "track": cmd_track, "export": cmd_export, "evaluate": cmd_evaluate, "merge": cmd_merge,
                "demo": cmd_demo, "front-end": cmd_front_end, "export-onnx": cmd_export_onnx, "methods": cmd_methods}
    from .interrupts import signals_raise

    try:
        with signals_raise():
            return commands[args.command](args)
    except (Interrupted, KeyboardInterrupt) as exc:
        signum = exc.signum if isinstance(exc, Interrupted) else 2
        kept = getattr(exc, "kept", None) or "no partial output was left behind"
        print(f"pmsr: interrupted by {_signal_name(signum)}; {kept}", file=sys.stderr)
        return 128 + signum
    except Exception as exc:
        if args.debug:
            raise
        code, line = describe_error(exc)
        print(f"pmsr: error: {line}", file=sys.stderr)
        return code


def _signal_name(signum: int) -> str:
    import signal

    return signal.Signals(signum).name


def describe_error(exc: BaseException) -> tuple[int, str]:
    """``(exit code, one line)`` for an exception escaping a command: 2 for anticipated failures
    (user input, files, resources), 1 for anything else (a bug: rerun with --debug)."""
    import errno

    if isinstance(exc, PmsrError):
        return 2, _one_line(str(exc))
    if isinstance(exc, OSError):
        what = exc.strerror or str(exc) or type(exc).__name__
        where = f": {exc.filename}" if exc.filename else ""
        if exc.errno == errno.ENOSPC:
            what = "no space left on the device"
        return 2, _one_line(f"{what}{where}")
    if isinstance(exc, UnicodeError):
        return 2, _one_line(f"a file is not UTF-8 text ({exc})")
    if isinstance(exc, MemoryError) or (isinstance(exc, RuntimeError) and "alloc" in str(exc).lower()):
        return 2, "out of memory; ask for less (fewer --tracks, --mc-runs or a smaller batch)"
    first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else ""
    return 1, (f"unexpected {type(exc).__name__}" + (f": {first}" if first else "")
               + "; this is a bug in pmsr_nn: rerun with --debug for the traceback and report it")


def _one_line(text: str, limit: int = 400) -> str:
    line = " ".join(text.split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def cmd_simulate(args) -> int:
    from .data.store import write_dataset
    from .simulation.recipe import load_recipe_for_simulation

    recipe, why_unsplit = load_recipe_for_simulation(args.recipe, tracks=args.tracks, seed=args.seed,
                                                     variant=args.variant, no_splits=args.no_splits)
    t0 = time.perf_counter()
    manifest = write_dataset(recipe, args.out, overwrite=args.overwrite, progress=not args.quiet, inputs=[args.recipe])
    seconds = time.perf_counter() - t0
    if not args.quiet:
        print(summarise(args.out, manifest, seconds, why_unsplit=why_unsplit))
    return 0


def _split_overrides(config: str | None, overrides: list[str]) -> tuple[str | None, list[str]]:
    if config is not None and "=" in config and not config.endswith((".yaml", ".yml")):
        return None, [config, *overrides]
    return config, list(overrides)


def cmd_train(args) -> int:
    from .nets.training import load_train_config, train

    config, overrides = _split_overrides(args.config, args.overrides)
    if config is None and not args.resume:
        raise PmsrError("give a training config (e.g. train/smoke.yaml), or --resume an existing run")
    cfg = load_train_config(config, overrides) if config is not None else None
    if args.resume and cfg is None and overrides:
        raise PmsrError("overrides need the config they apply to; a resumed run keeps its own config")
    m = train(cfg, args.out, resume=args.resume, console="lightning" if args.verbose else "lines")
    if m["global_rank"] != 0:  # DDP workers: rank 0 reports
        return 0
    print(f"run       {args.out}  ({m['epochs']} epochs, {m['global_step']} steps in {m['fit_seconds_this_session']:.0f} s"
          + (f", {m['train_windows_per_second']:.0f} windows/s)" if m['train_windows_per_second'] else ")"))
    print(f"val       position RMSE {m['val']['pos_rmse_m']:.2f} m, velocity RMSE {m['val']['vel_rmse_mps']:.3f} m/s "
          f"(best checkpoint {m['best_checkpoint']}; every sample of every window)")
    print(f"test      position RMSE {m['test']['pos_rmse_m']:.2f} m, velocity RMSE {m['test']['vel_rmse_mps']:.3f} m/s")
    print(f"tracker   {args.out / 'tracker.pt'}   (tensorboard --logdir {args.out / 'tb'})")
    return 0


def cmd_select(args) -> int:
    from .nets.selection import select_best
    from .nets.training import load_train_config

    cfg = load_train_config(args.config, args.overrides)
    result = select_best(cfg, args.out, members=args.members, fresh_tracks_n=args.fresh_tracks)
    print(result["table"])
    print(f"\nbest      member {result['best']} -> {args.out / 'best.pt'}")
    return 0


def cmd_track(args) -> int:
    from .data.sequences import read_measurements, write_estimates
    from .data.store import ARRAYS, is_our_dataset
    from .environment import resolve_device
    from .nets.inference import Tracker
    from .outputs import check_file_target
    from .plausibility import check_measurements

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
    estimates: list = [None] * len(seqs.z)
    for _, idx in seqs.by_length():
        import torch

        batch = tracker.track(torch.stack([seqs.z[i] for i in idx]), stride=args.stride, nan=args.nan)
        for j, i in enumerate(idx):
            estimates[i] = batch[j]
    seconds = time.perf_counter() - t0
    write_estimates(args.out, seqs, estimates, tracker.state_columns,
                    {"checkpoint": str(args.checkpoint), "input": str(args.input), "pmsr_nn": __version__,
                     "model": tracker.meta["model"]["kind"], "looks_ahead": tracker.looks_ahead},
                    overwrite=args.overwrite, inputs=inputs)
    steps = sum(len(z) for z in seqs.z)
    kind = "smoother (looks ahead)" if tracker.looks_ahead else "causal filter"
    print(f"tracked   {len(seqs.z)} sequence(s), {steps} scans with {tracker.meta['model']['kind']} ({kind}) in "
          f"{seconds:.2f} s -> {args.out}")
    import torch

    bad = sum(int((~torch.isfinite(e).all(-1)).sum()) for e in estimates)
    if bad:  # e.g. --force past the plausibility checks on values far outside the training span
        rows = [(seqs.track[i], int(seqs.rows[i][int(k)]) + 1) for i, e in enumerate(estimates)
                for k in torch.nonzero(~torch.isfinite(e).all(-1)).flatten()[:1]]
        print(f"warning   {bad} of {steps} estimates are not finite (NaN or inf), first at track {rows[0][0]!r} row "
              f"{rows[0][1]}: the input is outside what the network can track", file=sys.stderr)
    return 0


def cmd_export(args) -> int:
    from .data.sequences import read_dataset, write_csv_measurements

    import torch

    from .outputs import check_file_target

    check_file_target(args.out, overwrite=args.overwrite, inputs=[args.dataset], suffixes=(".csv",))
    seqs = read_dataset(args.dataset, args.split)
    z = torch.stack(seqs.z[: args.tracks] if args.tracks else seqs.z)
    write_csv_measurements(args.out, z, seqs.source["columns"], overwrite=args.overwrite, inputs=[args.dataset])
    print(f"wrote     {len(z)} track(s) x {z.shape[1]} scans -> {args.out}")
    return 0


def cmd_export_onnx(args) -> int:
    from .nets.inference import Tracker
    from .nets.onnx_export import check_with_onnxruntime, export_onnx
    from .outputs import atomic_file, check_file_target

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


def _checkpoint_overrides(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise PmsrError(f"--checkpoint expects NAME=PATH, got {item!r}")
        out[name] = path
    return out


def print_summary(res: dict) -> None:
    """The methods x cases position-RMSE table of a results.json, and the multi-target tables where
    a case has several targets."""
    from .harness.front_end_report import front_end_tables
    from .harness.report import multi_target_tables, summary_table

    fe = [line for line in front_end_tables(res) if line.startswith("|")]
    if fe:
        print("front end: signals -> detections, measured in this run\n" + "\n".join(fe) + "\n")
    print(f"position RMSE (m), Eq. 31 averaged after the warm-up; {res['mc_runs']} runs per case\n")
    print("\n".join(summary_table(res, None, "", False)))
    mt = [line for line in multi_target_tables(res, None, "paper") if not line.startswith("![")]
    if mt:
        print("\n" + "\n".join(mt).rstrip())
    from .harness.rd_maps_report import summary_lines

    tbd = summary_lines(res)  # the track-before-detect rows' per-frame figures
    if tbd:
        print("\n".join(tbd))


def cmd_evaluate(args) -> int:
    from .environment import resolve_device
    from .harness import evaluate
    from .harness.runner import parse_shard

    shard = parse_shard(args.shard)
    resolve_device(args.device)
    t0 = time.perf_counter()
    if args.executor:
        from .harness.dispatch import dispatch

        if shard != (1, 1):
            raise ConfigError("--executor runs every shard itself: give --shards N, not --shard I/N")
        res = dispatch(args.scenario, args.out, shards=args.shards, executor=args.executor, mc_runs=args.mc_runs,
                       checkpoints=_checkpoint_overrides(args.checkpoint), device=args.device,
                       overwrite=args.overwrite, partition=args.partition, timeout_min=args.timeout_min,
                       progress=not args.quiet)
        if not args.quiet:
            print_summary(res)
            print(f"\nreport    {args.out / 'report.md'}  ({time.perf_counter() - t0:.1f} s, {args.shards} "
                  f"{args.executor} jobs)")
        return 0
    res = evaluate(args.scenario, args.out, mc_runs=args.mc_runs, checkpoints=_checkpoint_overrides(args.checkpoint),
                   shard=shard, device=args.device, progress=not args.quiet, overwrite=args.overwrite)
    if args.quiet:
        return 0
    if shard != (1, 1):
        print(f"shard     {shard[0]}/{shard[1]} (blocks {res['blocks'][0]}..{res['blocks'][-1]}) -> {args.out} "
              f"in {time.perf_counter() - t0:.1f} s; combine all shards with 'pmsr merge'")
        return 0
    print_summary(res)
    print(f"\nreport    {args.out / 'report.md'}  ({time.perf_counter() - t0:.1f} s)")
    return 0


def cmd_front_end(args) -> int:
    from .frontend.recording import process_recording

    t0 = time.perf_counter()
    s = process_recording(args.recording, args.settings, args.out, overwrite=args.overwrite)
    print(f"front end {s['cpis']} CPIs -> {s['detections']} detections on {s['map'][0]} x {s['map'][1]} (Doppler x "
          f"range) maps, cancellation {s['cancellation_depth_db']:.1f} dB, {time.perf_counter() - t0:.1f} s -> "
          f"{args.out / 'detections.csv'}, {args.out / 'maps.h5'}")
    return 0


def cmd_methods(args) -> int:
    from .methods import catalogue

    print("\n".join(catalogue(args.kinds)).rstrip())
    return 0


def cmd_merge(args) -> int:
    from .harness import merge

    res = merge(args.shards, args.out, overwrite=args.overwrite)
    print_summary(res)
    print(f"\nreport    {args.out / 'report.md'}")
    return 0


def cmd_info(args) -> int:
    from .data.store import open_dataset

    from .outputs import atomic_file, check_file_target

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
        from .plots import plot_dataset_tracks

        with atomic_file(args.plot, overwrite=args.overwrite, inputs=[args.path], what="--plot", suffixes=(".png",)) as tmp:
            plot_dataset_tracks(args.path, tmp)
        print(f"figure    {args.plot}")
    return 0


def cmd_demo(args) -> int:
    from .harness.demo import demo_summary, run_demo

    print(f"pmsr demo: simulate, train two small networks, compare with EKF, UKF, SI+KF and the PCRB ({DEMO_EXPECTED})",
          flush=True)
    # Bars (with time left) only on a terminal: a log file keeps the one line per stage.
    res = run_demo(args.out, mc_runs=args.mc_runs, progress=sys.stderr.isatty(), verbose=args.verbose,
                   log=lambda line: print(line, flush=True))
    print("\n".join(demo_summary(res, args.out)))
    return 0


def summarise(path: Path, manifest: dict, seconds: float | None = None, why_unsplit: str | None = None) -> str:
    """A human-readable summary of a dataset: sizes, splits, envelope statistics, motion percentiles.
    ``why_unsplit``: why a dataset has no train/val split (appended to its splits line)."""
    from .data.store import open_dataset

    n, K, dx = manifest["shapes"]["states"]
    env = manifest["envelope"]
    splits = manifest["splits"]
    if not splits.get("train") and not splits.get("val"):  # every track a test track (simulate --no-splits)
        split_line = (f"splits    none: all {splits.get('test', n)} tracks are test tracks, for tracking, not training"
                      + (f"; {why_unsplit}" if why_unsplit else ""))
    else:
        split_line = ("splits    " + ", ".join(f"{k} {v} tracks / {manifest['windows'].get(k, 0)} windows"
                                               for k, v in splits.items())
                      + f"  (window {manifest['window']}, {manifest['windows_per_track']} per track)")
    lines = [
        f"dataset   {path}  ({manifest['name']}, variant '{manifest['variant']}', seed {manifest['seed']})",
        f"tracks    {n} x {K} samples (dt {manifest['dt_s']} s), state dim {dx}, measurement dim "
        f"{manifest['shapes']['measurements'][2]}, stored as {manifest['dtype']}",
        split_line,
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
