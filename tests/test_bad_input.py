"""The fault catalogue (``tests/faults/cases.py``: bad inputs and faults for ten of the ``pmsr``
commands), held to account.

Each case runs in a fresh sandbox (a copy of small fixtures: a dataset, a trained run, shards,
a folder of the user's own files and a file beside the working folder). Every file of the
sandbox is hashed before and after, and the outcome is classified exactly as the census
(``benchmarks/fault_census.py``) does (:mod:`faults.outcome`): a bad input must end with exit
code 2, one line ``pmsr: error: ...`` naming what is at fault, nothing changed and nothing left
behind; a valid input must succeed and touch nothing but its outputs (and print the warning a
case names in ``message``, if any).

The default run calls ``pmsr``'s ``main`` in-process for every case without a signal (a hang
would trip the case's alarm, 60 s unless it says otherwise). The cases that send a signal run as
real subprocesses in the slow tier (``make test-all``).
"""

import contextlib
import importlib.util
import io
import os
import signal
import sys
import time
import traceback
from pathlib import Path

import pytest
import torch

from faults import sandbox
from faults.cases import CASES
from faults.outcome import IS_ROOT, classify
from pmsr_nn.cli import main

ROOT = Path(__file__).resolve().parents[1]
IN_PROCESS = [c for c in CASES if c.signal is None]
SIGNALLED = [c for c in CASES if c.signal is not None]


def test_the_catalogue_is_wide_and_distinct():
    ids = [c.id for c in CASES]
    assert len(ids) == len(set(ids)) and len(CASES) >= 120
    plain = [(c.argv, c.signal) for c in CASES if c.setup is None]  # a setup makes its own input
    assert len(set(plain)) == len(plain)
    assert {c.command for c in CASES} == {"simulate", "info", "train", "select", "track", "export", "evaluate",
                                          "merge", "compare", "demo", "front-end"}


@pytest.fixture(scope="session")
def fixtures(tmp_path_factory):
    """Built once per test session: under pytest-xdist the workers share one build (in the folder
    above their own temporary folders, under a lock), since it takes half a minute."""
    def build(cache: Path) -> Path:
        return sandbox.build_fixtures(cache, ROOT, sys.executable, log=lambda m: None, run=_fixture_step)

    if "PYTEST_XDIST_WORKER" not in os.environ:
        return build(tmp_path_factory.mktemp("fault-fixtures"))
    from filelock import FileLock

    shared = tmp_path_factory.getbasetemp().parent / "fault-fixtures"
    shared.mkdir(exist_ok=True)
    with FileLock(str(shared / ".lock")):
        return build(shared)


def _fixture_step(argv: list[str], work: Path) -> tuple[int, str]:
    """One fixture step through ``main`` in this process (quiet, as the census's environment)."""
    saved = {k: os.environ.get(k) for k in ("TQDM_DISABLE", "MPLBACKEND")}
    os.environ.update(TQDM_DISABLE="1", MPLBACKEND="Agg")
    try:
        res = run_in_process(argv, work, 600.0)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return res["rc"], res["stdout"] + res["stderr"]


class _CaseTimeout(BaseException):
    pass


def _alarm(signum, frame):
    raise _CaseTimeout()


def run_in_process(argv, work: Path, timeout: float) -> dict:
    """``pmsr ARGV`` through ``main`` with cwd ``work``: the fields :func:`faults.outcome.classify` reads."""
    out, err = io.StringIO(), io.StringIO()
    threads, cwd = torch.get_num_threads(), os.getcwd()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    timed_out, t0 = False, time.monotonic()
    os.chdir(work)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = main(list(argv))
            except SystemExit as exc:  # argparse
                rc = exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1
            except _CaseTimeout:
                timed_out, rc = True, -9
            except BaseException:  # anything escaping main is a traceback, as a subprocess would show
                traceback.print_exc()
                rc = 1
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        os.chdir(cwd)
        torch.set_num_threads(threads)  # a guard: trainings give their threads back themselves (pmsr_nn.nets.torch_settings)
    return {"rc": rc, "stdout": out.getvalue(), "stderr": err.getvalue(), "timed_out": timed_out,
            "seconds": time.monotonic() - t0, "maxrss_mb": None, "signal_sent_at": None}


def check(c, fixtures, tmp_path, run):
    case_dir = tmp_path / "case"
    work = sandbox.make_sandbox(fixtures, case_dir)
    if c.setup is not None:
        c.setup(work)
    expect = c.root_expect if (IS_ROOT and c.root_expect) else c.expect
    before = sandbox.snapshot(case_dir)
    res = run(c, work)
    changes = sandbox.diff_snapshots(before, sandbox.snapshot(case_dir))
    verify = c.verify(work) if (expect == "ok" and res["rc"] == 0 and c.verify is not None) else None
    klass, reason = classify(c, expect, res, changes, verify)
    assert klass == ("ok" if expect == "ok" else "clean_refusal"), \
        f"{klass}: {reason}\nstderr: {res['stderr'][-1500:]}"
    if c.message and c.signal is None and expect == c.expect:  # a refusal's error line, or an accepted input's warning
        assert c.message.lower() in res["stderr"].lower(), f"stderr does not say {c.message!r}: {res['stderr']}"
    sandbox.rmtree_force(case_dir)


@pytest.fixture
def quiet_env(monkeypatch):
    monkeypatch.setenv("TQDM_DISABLE", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.delenv("PMSR_TRAIN_RUN", raising=False)


@pytest.mark.parametrize("c", IN_PROCESS, ids=lambda c: c.id)
def test_bad_input(c, fixtures, tmp_path, quiet_env):
    check(c, fixtures, tmp_path, lambda c, work: run_in_process(c.argv, work, c.timeout))


def _census():
    spec = importlib.util.spec_from_file_location("fault_census", ROOT / "benchmarks" / "fault_census.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
@pytest.mark.parametrize("c", SIGNALLED, ids=lambda c: c.id)
def test_signal(c, fixtures, tmp_path):
    census = _census()
    env = sandbox.pmsr_env(ROOT, tmp_path / "cache")
    logs = tmp_path / "logs"
    logs.mkdir()
    check(c, fixtures, tmp_path,
          lambda c, work: census.run_process(c, work, ROOT, sys.executable, c.timeout, logs, env))
