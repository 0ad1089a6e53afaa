"""``pmsr evaluate`` (a scenario's methods on the same Monte Carlo draws, or a shard of them) and
``pmsr merge`` (the shards into the whole run's results)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from ..errors import ConfigError, PmsrError
from .common import mc_runs_int, nonneg_int, positive_int


def add_evaluate(sub) -> None:
    ev = sub.add_parser(
        "evaluate",
        help="run every method of a scenario on the same Monte Carlo draws",
        description="Run a scenario (evaluate/*.yaml): every method on the same truth and measurement draws, "
        "the PCRB of each case; write OUT/results.json, OUT/report.md and PNG figures. With --shard I/N only a "
        "slice of the Monte Carlo runs is run and OUT holds shard.json + blocks.npz for 'pmsr merge'.",
    )
    ev.add_argument("scenario", type=Path, help="scenario YAML, e.g. evaluate/fitee2023_three_trajectories.yaml")
    ev.add_argument("--out", type=Path, required=True, help="output folder (new or empty unless --overwrite)")
    ev.add_argument("--mc-runs", type=mc_runs_int, help="Monte Carlo runs per case (overrides the scenario's)")
    ev.add_argument("--seed", type=nonneg_int, help="draw the truth and measurements from this seed (overrides the "
                    "scenario's 'seed:'; recorded in results.json): other runs of the same scenario, e.g. to choose "
                    "a setting on draws that are not the recorded ones")
    ev.add_argument("--methods", metavar="NAME[,NAME...]",
                    help="run only these rows: names from the scenario's 'methods:' list, comma-separated (a case "
                         "that names its own methods keeps those of them that are given)")
    ev.add_argument("--checkpoint", action="append", default=[], metavar="NAME=PATH",
                    help="use this checkpoint for method NAME, of any kind that reads one (learned, "
                    "nebp; repeatable)")
    ev.add_argument("--shard", default="1/1", metavar="I/N", help="run the I-th of N slices of the runs (default 1/1: all)")
    ev.add_argument("--per-block", action="store_true",
                    help="write each block of runs as soon as it is done, as its own shard folder OUT/block-NNNN; "
                    "blocks already in OUT (or being run by another process) are skipped, so the same command "
                    "continues an interrupted recording and several processes can fill one bank; combine with "
                    "'pmsr merge OUT'")
    ev.add_argument("--workers", metavar="N",
                    help="worker processes, one thread each, that share the blocks of runs (default: every core, or "
                         "$PMSR_WORKERS; 1 on a GPU); the figures are one process's, bit for bit")
    ev.add_argument("--batch-runs", metavar="N", default=1, type=positive_int,
                    help="call each tracker that allows it on N runs at once, in whole blocks of runs (default 1: "
                         "block by block); in a study of one-run blocks those trackers run 1.4-8x faster per run "
                         "(benchmarks/RESULTS.md), the draws unchanged")
    ev.add_argument("--device", default="cpu", help="torch device the methods run on (default cpu; the draws and the scoring stay on the CPU; docs/cli.md lists the kinds that run on a GPU)")
    ev.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    ev.add_argument("--quiet", action="store_true", help="no progress bar and no table")
    ev.add_argument("--executor", choices=("local", "slurm"),
                    help="run the scenario as --shards jobs of submitit on this machine (local) or a SLURM array "
                    "(slurm), then merge them into --out")
    ev.add_argument("--shards", type=int, default=2, help="jobs for --executor (default 2; at most the blocks of runs)")
    ev.add_argument("--partition", help="SLURM partition for --executor slurm")
    ev.add_argument("--timeout-min", type=int, default=60, help="time limit per shard job for --executor (default 60)")
    ev.set_defaults(run=cmd_evaluate)


def add_merge(sub) -> None:
    mg = sub.add_parser("merge", help="combine the shards of a scenario run",
                        description="Combine the output folders of 'pmsr evaluate --shard I/N' runs (all N of them) "
                        "into the results, report and figures of the whole run.")
    mg.add_argument("shards", type=Path, nargs="+", help="shard output folders, or block banks of --per-block")
    mg.add_argument("--out", type=Path, required=True, help="output folder")
    mg.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    mg.add_argument("--runs", type=mc_runs_int, metavar="K",
                    help="merge only the first K runs (whole blocks; later shards are left out): a preview of a "
                    "recording still running, marked as one")
    mg.set_defaults(run=cmd_merge)


def checkpoint_overrides(items: list[str]) -> dict[str, str]:
    """``--checkpoint NAME=PATH`` arguments as ``{NAME: PATH}``."""
    out = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise PmsrError(f"--checkpoint expects NAME=PATH, got {item!r}")
        out[name] = path
    return out


def method_names(text: str, known: list[str]) -> list[str]:
    """The names of ``--methods NAME[,NAME...]`` (a whole argument that is one of the ``known`` names is one name)."""
    if text.strip() in known:
        return [text.strip()]
    return [name.strip() for name in text.split(",") if name.strip()]


def keep_methods(sc, names: list[str]):
    """Scenario ``sc`` (a designed scenario or a multi-target study) with only the methods ``names``
    (its report rows), in the scenario's order. A case that names the methods it runs keeps those of
    them in ``names``; one left with none is dropped. What a case computes besides its rows (the
    PCRB of each case) is kept. An unknown name: a :class:`ConfigError` listing the rows."""
    known = [m.name for m in sc.methods]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        given = ", ".join(repr(n) for n in unknown) if unknown else "nothing"
        raise ConfigError(f"--methods {given}: not {'a row' if len(unknown) == 1 else 'rows'} of scenario "
                          f"{sc.name!r}, whose rows are: {', '.join(known)}")
    keep = set(names)
    cases = []
    for c in sc.cases:
        own = getattr(c, "methods", ())  # a designed case may name the methods it runs (all if none)
        if not own:
            cases.append(c)
        elif keep.intersection(own):
            cases.append(dataclasses.replace(c, methods=tuple(n for n in own if n in keep)))
    if not cases:
        raise ConfigError(f"--methods {', '.join(names)}: no case of scenario {sc.name!r} runs these methods")
    new = dataclasses.replace(sc, methods=tuple(m for m in sc.methods if m.name in keep), cases=tuple(cases))
    object.__setattr__(new, "base_dir", sc.base_dir)  # not an init field: replace() resets it
    return new


def print_summary(res: dict) -> None:
    """The methods x cases position-RMSE table of a results.json, the multi-target tables where
    a case has several targets, and the report's warnings."""
    from ..harness.report.front_end_report import front_end_tables
    from ..harness.report.method_tables import summary_table
    from ..harness.report.multitarget_tables import multi_target_tables

    fe = [line for line in front_end_tables(res) if line.startswith("|")]
    if fe:
        print("front end: signals -> detections, measured in this run\n" + "\n".join(fe) + "\n")
    preview = res.get("environment", {}).get("preview_of_runs")
    if preview:
        print(f"A PREVIEW: the first {res['mc_runs']} of the scenario's {preview} runs (a recording in progress)\n")
    print(f"position RMSE (m), Eq. 31 averaged after the warm-up; {res['mc_runs']} runs per case\n")
    print("\n".join(summary_table(res, None, "", False)))
    mt = [line for line in multi_target_tables(res, None, "paper") if not line.startswith("![")]
    if mt:
        print("\n" + "\n".join(mt).rstrip())
    from ..harness.report.rd_maps_report import summary_lines

    tbd = summary_lines(res)  # the track-before-detect rows' per-frame figures
    if tbd:
        print("\n".join(tbd))
    from ..harness.report.flags import warning_lines

    warnings = warning_lines(res)  # what the report flags (below a bound beyond its error, diverged runs)
    if warnings:
        print("\n" + "\n".join(warnings))


def cmd_evaluate(args) -> int:
    from ..environment import resolve_device
    from ..harness import evaluate
    from ..harness.run.block_sums import parse_shard

    shard = parse_shard(args.shard)
    resolve_device(args.device)
    t0 = time.perf_counter()
    if args.workers is not None:
        from ..harness.workers import check_workers

        check_workers(args.workers)
        for given, what in ((args.executor, "--executor (its jobs are the processes)"),
                            (args.per_block, "--per-block (start one command per process)"),
                            (shard != (1, 1), "--shard (a shard runs in one process)")):
            if given:
                raise ConfigError(f"--workers runs the whole scenario on this machine: give it or {what}, not both")
    if args.executor:
        from ..harness.dispatch import dispatch

        if args.per_block:
            raise ConfigError("--per-block banks the blocks of one process; the jobs of --executor write whole shards: "
                              "give one or the other")
        if shard != (1, 1):
            raise ConfigError("--executor runs every shard itself: give --shards N, not --shard I/N")
        if args.methods is not None:
            raise ConfigError("--methods does not reach the jobs of --executor: run each shard with --shard I/N "
                              "--methods ... and combine them with 'pmsr merge'")
        if args.batch_runs != 1:
            raise ConfigError("--batch-runs does not reach the jobs of --executor: run each shard with --shard I/N "
                              "--batch-runs N and combine them with 'pmsr merge'")
        res = dispatch(args.scenario, args.out, shards=args.shards, executor=args.executor, mc_runs=args.mc_runs,
                       checkpoints=checkpoint_overrides(args.checkpoint), device=args.device, seed=args.seed,
                       overwrite=args.overwrite, partition=args.partition, timeout_min=args.timeout_min,
                       progress=not args.quiet)
        if not args.quiet:
            print_summary(res)
            print(f"\nreport    {args.out / 'report.md'}  ({time.perf_counter() - t0:.1f} s, {args.shards} "
                  f"{args.executor} jobs)")
        return 0
    if args.per_block and args.overwrite:
        raise ConfigError("--per-block continues the bank at --out and never replaces it: drop --overwrite (or give a "
                          "new --out)")
    scenario, checkpoints, runs = args.scenario, checkpoint_overrides(args.checkpoint), args.mc_runs
    if args.methods is not None:
        from ..harness.run.runner import RESULT_COMMANDS
        from ..harness.scenario.loading import load_any
        from ..outputs import check_folder_target

        # the scenario file is an input even when evaluate() is handed the loaded scenario; a bank (--per-block) is
        # checked by open_run, which continues one that exists
        if not args.per_block:
            check_folder_target(args.out, overwrite=args.overwrite, inputs=[args.scenario], allow=RESULT_COMMANDS)
        sc = load_any(args.scenario, runs, checkpoints, args.seed)
        scenario, checkpoints, runs = keep_methods(sc, method_names(args.methods, [m.name for m in sc.methods])), None, None
    if args.per_block:
        from ..harness.evaluate import execute
        from ..harness.run.runner import open_run

        execute(open_run(scenario, args.out, target="bank", shard=shard, mc_runs=runs, checkpoints=checkpoints,
                         seed=args.seed, device=args.device, progress=not args.quiet, source=args.scenario,
                         batch_runs=args.batch_runs))
        return 0
    if shard == (1, 1):
        from ..harness.workers import check_workers, default_workers, evaluate_in_workers

        workers = default_workers(args.device) if args.workers is None else check_workers(args.workers)
        res = evaluate_in_workers(scenario, args.out, workers=workers, mc_runs=runs, checkpoints=checkpoints,
                                  seed=args.seed, device=args.device, overwrite=args.overwrite, progress=not args.quiet,
                                  source=args.scenario if scenario is not args.scenario else None,
                                  warn=args.workers is not None, batch_runs=args.batch_runs)
    else:
        res = evaluate(scenario, args.out, mc_runs=runs, checkpoints=checkpoints, shard=shard, device=args.device,
                       progress=not args.quiet, overwrite=args.overwrite, seed=args.seed, batch_runs=args.batch_runs)
    if args.quiet:
        return 0
    if shard != (1, 1):
        print(f"shard     {shard[0]}/{shard[1]} (blocks {res['blocks'][0]}..{res['blocks'][-1]}) -> {args.out} "
              f"in {time.perf_counter() - t0:.1f} s; combine all shards with 'pmsr merge'")
        return 0
    print_summary(res)
    print(f"\nreport    {args.out / 'report.md'}  ({time.perf_counter() - t0:.1f} s)")
    return 0


def cmd_merge(args) -> int:
    from ..harness import merge

    res = merge(args.shards, args.out, overwrite=args.overwrite, runs=args.runs)
    print_summary(res)
    print(f"\nreport    {args.out / 'report.md'}")
    return 0
