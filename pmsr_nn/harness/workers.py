"""``pmsr evaluate --workers N``: a scenario's blocks run by N processes of this machine, one
thread each, then merged into the results folder: the figures of one process, bit for bit,
timings aside (the merge of a block bank, :mod:`.run.block_bank` and :mod:`.run.merge`).

The workers fill a block bank in a staging folder beside the output, ``.<out>.blocks``: each
claims a block no other holds, runs it and files it (the bank's claims are what keeps two workers
off one block). Nothing is written to ``out`` until every block is there; the merge then writes
it atomically and the staging bank, which this command made, goes. A worker that fails stops the
others; the blocks already filed stay in the staging bank, and the same command run again
continues from them (so does one interrupted by a signal).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import shutil
import sys
import time
from pathlib import Path

from ..errors import ConfigError, OutputError, PmsrError
from ..outputs import MARKER, foreign_files, is_ours
from .run.block_bank import BANK_FILE, bank_blocks, is_bank, open_bank
from .run.runner import RESULT_COMMANDS, open_run

WORKERS_ENV = "PMSR_WORKERS"
"""Environment variable that sets ``pmsr evaluate``'s default number of workers (the test suite
sets 1); without it the default is every core."""


def default_workers(device: str = "cpu") -> int:
    """``pmsr evaluate``'s workers when ``--workers`` is not given: ``$PMSR_WORKERS``, else on the
    CPU the cores this process may use, on another device 1 (the processes would share it)."""
    if os.environ.get(WORKERS_ENV):
        return check_workers(os.environ[WORKERS_ENV], f"${WORKERS_ENV}")
    if device != "cpu":
        return 1
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def check_workers(value, what: str = "--workers") -> int:
    """A positive number of workers, or a one-line refusal."""
    try:
        n = int(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{what} must be a positive whole number of worker processes, got {value!r}") from None
    if n < 1:
        raise ConfigError(f"{what} must be at least 1 (one worker process per core at most), got {n}")
    return n


def staging_bank(out: Path) -> Path:
    """The staging block bank of output folder ``out``: ``.<name>.blocks`` beside it."""
    out = Path(out)
    return out.parent / f".{out.name}.blocks"


def _work(scenario, bank: Path, options: dict) -> None:
    """One worker: one thread, the bank's unclaimed blocks until none is left. An error is one
    line on stderr, as the command's own (exit 2 for bad input, 1 for anything else)."""
    import torch

    torch.set_num_threads(1)
    from .evaluate import execute

    try:
        execute(open_run(scenario, bank, target="bank", progress=False, **options))
    except PmsrError as exc:
        print(f"pmsr: error: {mp.current_process().name}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    except Exception as exc:  # a bug: one line, as the command's own handler gives it
        print(f"pmsr: error: {mp.current_process().name}: unexpected {type(exc).__name__}: {exc}", file=sys.stderr)
        raise SystemExit(1) from None


def evaluate_in_workers(scenario, out: Path, *, workers: int, mc_runs: int | None = None,
                        checkpoints: dict[str, str] | None = None, seed: int | None = None, device: str = "cpu",
                        overwrite: bool = False, progress: bool = True, source: Path | None = None,
                        warn: bool = True, log=print, batch_runs: int = 1) -> dict:
    """Run ``scenario`` (a YAML file, or a loaded scenario with ``source`` its file) with
    ``workers`` processes into ``out`` (module docstring); returns results.json's content. More
    workers than blocks: one per block, with a warning where ``warn``; one in all: this process
    runs the scenario itself (:func:`~.evaluate.evaluate`)."""
    from .evaluate import evaluate, merge
    from ..outputs import check_folder_target

    out = Path(out)
    files = [Path(source)] if source is not None else [Path(scenario)] if isinstance(scenario, (str, Path)) else []
    check_folder_target(out, overwrite=overwrite, inputs=files, allow=RESULT_COMMANDS)
    bank = staging_bank(out)
    if bank.exists() and not is_bank(bank) and any(bank.iterdir()):
        raise OutputError(f"{bank}, where --workers stages the blocks of {out}, holds something else; move it away")
    options = {"mc_runs": mc_runs, "checkpoints": checkpoints, "seed": seed, "device": device, "source": source,
               "batch_runs": batch_runs}
    run = open_run(scenario, bank, target="bank", progress=False, **options)  # refusals before any worker starts
    n_blocks = run.scenario.n_blocks
    if workers > n_blocks:
        if warn:
            print(f"warning: --workers {workers} is more than the {n_blocks} block(s) of runs; {n_blocks} worker(s) "
                  "run", file=sys.stderr)
        workers = n_blocks
    if workers == 1 and not bank.exists():  # nothing to share out, nothing banked to continue from
        return evaluate(scenario, out, mc_runs=mc_runs, checkpoints=checkpoints, device=device, progress=progress,
                        overwrite=overwrite, seed=seed, batch_runs=batch_runs)
    try:
        note = open_bank(run)  # here, not in the workers: a foreign bank is one line before any starts
    except ConfigError:
        raise ConfigError(f"{bank}, where --workers stages the blocks of {out}, holds blocks of another scenario or "
                          "other settings (an earlier command's); move it away, or run that command again") from None
    if note and progress:
        log(note)
    ctx = mp.get_context("spawn")  # a fresh interpreter each: no state forked from this one
    env_threads = os.environ.get("OMP_NUM_THREADS")
    os.environ["OMP_NUM_THREADS"] = "1"  # read by the workers' torch at start-up
    try:
        procs = [ctx.Process(target=_work, args=(scenario, bank, options), name=f"pmsr-worker-{i}")
                 for i in range(workers)]
        for p in procs:
            p.start()
    finally:
        if env_threads is None:
            os.environ.pop("OMP_NUM_THREADS", None)
        else:
            os.environ["OMP_NUM_THREADS"] = env_threads
    try:
        _wait(procs, bank, n_blocks, progress, log)
    except BaseException:
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join()
        raise
    res = merge([bank], out, device=device, overwrite=overwrite)
    kept = remove_staging(bank)
    if kept:
        print(f"warning: {bank} keeps {len(kept)} file(s) this command did not write ({kept[0]}{', ...' if len(kept) > 1 else ''}); "
              "the staging bank's own files are gone", file=sys.stderr)
    return res


def remove_staging(bank: Path) -> list[str]:
    """Remove staging bank ``bank`` (``.<out>.blocks``, beside an output checked to be no input,
    working folder or parent of it) as far as it is the bank's own: its ``bank.json`` and marker,
    and each ``block-NNNN`` folder that carries our marker and holds nothing its marker does not
    list; the folder itself only once empty. Returns what was left (anything else found there)."""
    bank = Path(bank)
    if bank.is_symlink() or not is_bank(bank):
        return [bank.name]
    left, blocks = [], set(bank_blocks(bank))
    for entry in sorted(bank.iterdir()):
        if entry.name in (BANK_FILE, MARKER) and entry.is_file() and not entry.is_symlink():
            entry.unlink()
        elif entry in blocks and not entry.is_symlink() and is_ours(entry) and not foreign_files(entry):
            shutil.rmtree(entry)
        else:
            left.append(entry.name)
    if not left:
        bank.rmdir()
    return left


def _wait(procs, bank: Path, n_blocks: int, progress: bool, log) -> None:
    """Until every worker has ended; a failed one stops the rest (one line: what is kept)."""
    done, shown = 0, -1
    while True:
        alive = [p for p in procs if p.is_alive()]
        failed = [p for p in procs if not p.is_alive() and p.exitcode not in (0, None)]
        if failed:
            raise ConfigError(f"worker {failed[0].name} stopped with exit code {failed[0].exitcode} (its line is above); "
                              f"the blocks done are kept in {bank}: run the same command again to continue")
        done = len(bank_blocks(bank))
        if progress and done != shown:
            log(f"workers: {done} of {n_blocks} block(s) done ({len(alive)} worker(s) running)")
            shown = done
        if not alive:
            break
        time.sleep(0.5)
    if done < n_blocks:
        raise ConfigError(f"the workers ended with {done} of {n_blocks} block(s) done; the blocks done are kept in "
                          f"{bank}: run the same command again to continue")
