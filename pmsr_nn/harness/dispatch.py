"""``pmsr evaluate --executor local|slurm``: the shards of a scenario as jobs of an existing engine.

`submitit <https://github.com/facebookincubator/submitit>`_ runs ``pmsr evaluate --shard I/N``
for each ``I`` as one job of an array, on this machine (``local``: one process per shard) or on
a SLURM cluster (``slurm``: one array task per shard, submitted from a login node; the shared
file system holds the scenario, the checkpoints and the output's parent folder), waits for
them, and merges the shards with :func:`~pmsr_nn.harness.evaluate.merge`: the figures of the
unsharded run, bit for bit, timings aside.

The shards and the engine's logs live in a staging folder beside ``out``
(``.<out>.shards-<pid>``) that this command creates and removes; nothing is written to ``out``
unless every shard succeeded (the merge is atomic like every results folder). A shard that fails
or is killed, or a signal to this command, stops every job (local ones killed, SLURM ones
cancelled) before the staging folder goes: no orphan writes on. The call is not resumable: run it
again (``--per-block`` is the resumable way to fill one result from several processes).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from ..errors import ConfigError, OutputError
from ..outputs import PARTIAL_MARKER, make_parents, remove_if_empty

EXECUTORS = ("local", "slurm")


def _submitit():
    try:
        import submitit
    except ImportError:
        raise ConfigError("--executor needs submitit, which this installation lacks: pip install "
                          "'pmsr_nn[cluster]' (or pip install submitit)") from None
    return submitit


def check_cluster(executor: str) -> None:
    """Refuse ``slurm`` in one line where no SLURM cluster is reachable (``srun`` / ``sbatch`` not
    on PATH): submitit would fail with a traceback of its own, and the user needs ``local``."""
    missing = [tool for tool in ("srun", "sbatch") if shutil.which(tool) is None]
    if executor == "slurm" and missing:
        raise ConfigError(f"--executor slurm: no SLURM cluster found ({' and '.join(missing)} not on PATH); run on "
                          "this machine with --executor local, or without --executor")


def run_shard(scenario: str, out: str, shard: tuple[int, int], mc_runs: int | None, checkpoints: dict | None,
              device: str, seed: int | None = None) -> str:
    """One job: shard ``shard`` of ``scenario`` into ``out`` (what ``pmsr evaluate --shard`` does)."""
    from .evaluate import evaluate

    evaluate(Path(scenario), Path(out), mc_runs=mc_runs, checkpoints=checkpoints, shard=tuple(shard), device=device,
             progress=False, seed=seed)
    return out


def dispatch(scenario: str | Path, out: Path, *, shards: int, executor: str = "local", mc_runs: int | None = None,
             checkpoints: dict[str, str] | None = None, device: str = "cpu", overwrite: bool = False,
             partition: str | None = None, timeout_min: int = 60, progress: bool = True,
             seed: int | None = None) -> dict:
    """Run ``scenario`` as ``shards`` jobs on ``executor`` and merge them into ``out``; returns
    results.json's content. ``partition`` and ``timeout_min`` (per shard) are SLURM's. The run is
    opened here (:func:`~.run.runner.open_run`: a method that can not run is refused before any job
    is submitted); each job opens and executes its shard's, and the merge executes the whole."""
    from .evaluate import merge
    from .run.runner import open_run

    if executor not in EXECUTORS:
        raise ConfigError(f"--executor must be one of {', '.join(EXECUTORS)}, got {executor!r}")
    check_cluster(executor)  # before submitit is asked: off a cluster it is the cluster that is missing
    submitit = _submitit()
    out = Path(out)
    scenario = Path(scenario)

    def check(sc) -> None:
        if not 1 <= shards <= sc.n_blocks:
            raise ConfigError(f"--shards must be in 1..{sc.n_blocks} (the scenario's blocks of runs), got {shards}")
        if not isinstance(timeout_min, int) or timeout_min < 1:
            raise ConfigError(f"--timeout-min must be a positive number of minutes, got {timeout_min}")

    sc = open_run(scenario, out, mc_runs=mc_runs, checkpoints=checkpoints, seed=seed, device=device,
                  overwrite=overwrite, check=check).scenario
    made = make_parents(out)
    work = out.parent / f".{out.name}.shards-{os.getpid()}"
    try:
        work.mkdir()  # fails if the name is taken: then nothing below may remove it
    except OSError as exc:
        remove_if_empty(made)
        raise OutputError(f"--out {out}: cannot create the staging folder {work} ({exc.strerror})") from None
    (work / PARTIAL_MARKER).touch()  # proves the folder is ours when it is removed
    jobs: list = []
    try:
        engine = submitit.AutoExecutor(folder=work / "logs", cluster=executor)
        params = {"timeout_min": timeout_min, "name": f"pmsr-{sc.name}"}
        if executor == "slurm":
            params["slurm_array_parallelism"] = shards
            if partition:
                params["slurm_partition"] = partition
        engine.update_parameters(**params)
        folders = [str(work / f"shard{i}") for i in range(1, shards + 1)]
        jobs = engine.map_array(run_shard, [str(scenario.resolve())] * shards, folders,
                                [(i, shards) for i in range(1, shards + 1)], [mc_runs] * shards,
                                [checkpoints] * shards, [device] * shards, [seed] * shards)
        if progress:
            print(f"submitted {shards} shard job(s) to {executor}: {', '.join(str(j.job_id) for j in jobs)}")
        for i, job in enumerate(jobs, start=1):
            try:
                job.result()
            except Exception as exc:  # the job's own error, re-raised by submitit with its traceback
                raise ConfigError(f"shard {i}/{shards} (job {job.job_id}) {_failure(exc)}") from None
        jobs = []  # all done: nothing to stop
        return merge([Path(f) for f in folders], out, device=device, overwrite=overwrite)
    finally:
        _stop(jobs, work, cluster=executor == "slurm")  # a failed or interrupted call leaves no job running on
        if (work / PARTIAL_MARKER).is_file():  # only the staging folder this call created
            shutil.rmtree(work, ignore_errors=True)
        remove_if_empty(made)  # parents made for the output, when the merge left nothing in them


def _failure(exc: BaseException) -> str:
    """What became of a shard job, from the error submitit re-raises: its own last error line, or,
    where it ended without a result (killed, out of memory), that."""
    if type(exc).__name__ == "UncompletedJobError":
        return "ended without a result: its process was killed or died (out of memory, a signal, the node)"
    text = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip() and not ln.startswith("submitit ")]
    return f"failed: {(text[-1] if text else type(exc).__name__)[:300]}"


def _stop(jobs: list, work: Path, cluster: bool, wait_s: float = 10.0) -> None:
    """Stop what still runs of ``jobs``: on a cluster, cancel them (scancel); on this machine, kill
    (SIGKILL, which prints nothing: their output is discarded with the staging folder) every
    process with the staging folder ``work`` on its command line, each job's controller and its
    task alike (a task whose controller was killed lives on as an orphan that would write into
    ``work``), and wait until they are gone."""
    import signal
    import time

    if cluster:
        for job in jobs:
            try:
                job.cancel(check=False)
            except Exception:  # noqa: BLE001 - a job that is already gone, or a cluster that can not be reached
                pass
    mine, deadline = str(work).encode(), time.time() + wait_s
    while time.time() < deadline:
        alive = []
        for proc in Path("/proc").glob("[0-9]*"):
            try:
                if mine in proc.joinpath("cmdline").read_bytes() and int(proc.name) != os.getpid():
                    alive.append(int(proc.name))
            except (OSError, ValueError):
                continue  # gone meanwhile, or not ours to read
        if not alive:
            return
        for pid in alive:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        time.sleep(0.05)
