"""Nothing lost under load (issue "Nothing lost, round three"): a multi-process ``pmsr evaluate``
killed mid-run and resumed gives the uninterrupted run's figures bit for bit, and a disk that
fills mid-run ends the command with one line, no half-written output and no earlier result lost.

* **Kill and resume.** Several ``--per-block`` processes fill one bank (the package's resumable
  multi-process mode): one is killed outright (SIGKILL: its claim and half-run block stay behind),
  the other interrupted (SIGINT: one line, its claim released); the same command then continues
  the bank, and its merge equals an uninterrupted ``pmsr evaluate``. ``--executor local`` (one
  submitit process per shard) is not resumable: SIGKILL to one of its workers and SIGINT to the
  parent must leave no output and no staging folder, and the rerun gives the same figures.
* **Disk full.** ``pmsr evaluate`` runs on a small tmpfs mounted in a private mount namespace
  (``unshare -rm``: no root needed where user namespaces are allowed; skipped elsewhere) that is
  filled to within a few kB before the run: exit code 2, the one line ``pmsr: error: no space left
  on the device``, no new folder or ``.partial`` leftover, and the earlier results folder on the
  same disk byte for byte as it was.

The default tier runs one quick version of each; the slow tier the two-process kill, the
executor and every disk margin.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import yaml

from test_harness import accuracy

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
rng = random.Random(20261207)


def scenario(root: Path, mc_runs: int, block_runs: int = 1) -> Path:
    """A single-target scenario of ``mc_runs`` runs in blocks of ``block_runs`` (EKF, UKF)."""
    d = {"name": "load", "seed": 11, "mc_runs": mc_runs, "block_runs": block_runs, "warmup_steps": 20,
         "cases": [{"name": "t1", "start_range_m": 4000.0, "start_bearing_deg": 130.0, "speed_mps": 10.0,
                    "heading_deg": 20.0, "segments": [{"duration_s": 80.0}]}],
         "methods": [{"name": "EKF", "kind": "ekf"}, {"name": "UKF", "kind": "ukf"}]}
    path = root / "sc.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def pmsr(args, cwd) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "pmsr_nn.cli", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV)


def finish(args, cwd, timeout=600) -> str:
    p = pmsr(args, cwd)
    out, err = p.communicate(timeout=timeout)
    assert p.returncode == 0, err
    return out


def figures(results: Path) -> dict:
    """results.json without the timings and the environment: what must be bit-identical."""
    return accuracy(json.loads(results.read_text()))


def wait_for(condition, proc, timeout=120.0) -> None:
    deadline = time.time() + timeout
    while not condition() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    assert proc.poll() is None, f"the command ended before it could be interrupted: {proc.communicate()}"


def blocks(bank: Path) -> list[str]:
    return sorted(p.name for p in bank.glob("block-[0-9]*") if p.is_dir())


_REFERENCE: dict[int, dict] = {}


def reference(root: Path, runs: int) -> dict:
    """The figures of an uninterrupted run of the ``runs``-run scenario (in-process, once per session)."""
    from pmsr_nn.cli import main

    if runs not in _REFERENCE:
        folder = root / f"reference-{runs}"
        folder.mkdir()
        assert main(["evaluate", str(scenario(folder, runs)), "--out", str(folder / "ev"), "--quiet"]) == 0
        _REFERENCE[runs] = figures(folder / "ev" / "results.json")
    return _REFERENCE[runs]


# -- kill and resume ---------------------------------------------------------------------------------

@pytest.mark.integration
def test_a_bank_worker_killed_outright_is_resumed_to_the_uninterrupted_figures(tmp_path, tmp_path_factory):
    from pmsr_nn.cli import main

    sc = scenario(tmp_path, 8)
    p = pmsr(["evaluate", "sc.yaml", "--out", "bank", "--per-block", "--quiet"], tmp_path)
    wait_for(lambda: len(blocks(tmp_path / "bank")) >= 1, p)
    p.send_signal(signal.SIGKILL)
    p.communicate(timeout=60)
    assert p.returncode == -signal.SIGKILL
    done = blocks(tmp_path / "bank")
    assert 1 <= len(done) < 8, done  # really cut short
    bank = tmp_path / "bank"
    assert main(["evaluate", str(sc), "--out", str(bank), "--per-block", "--quiet"]) == 0  # the same command
    assert blocks(bank) == [f"block-{b:04d}" for b in range(8)]
    assert not list(bank.glob(".*claim*")) and not list(bank.glob("*.partial*"))
    assert main(["merge", str(bank), "--out", str(tmp_path / "merged")]) == 0
    assert figures(tmp_path / "merged" / "results.json") == reference(tmp_path_factory.getbasetemp(), 8)


@pytest.mark.slow
def test_two_bank_workers_one_killed_one_interrupted_resume_to_the_uninterrupted_figures(tmp_path, tmp_path_factory):
    scenario(tmp_path, 12)
    args = ["evaluate", "sc.yaml", "--out", "bank", "--per-block", "--quiet"]
    a, b = pmsr(args, tmp_path), pmsr(args, tmp_path)
    first = rng.randint(2, 5)
    wait_for(lambda: len(blocks(tmp_path / "bank")) >= first, a)
    a.send_signal(signal.SIGKILL)
    time.sleep(rng.uniform(0.0, 1.0))
    assert b.poll() is None, "the second worker ended before it could be interrupted"
    b.send_signal(signal.SIGINT)
    _, err_a = a.communicate(timeout=60)
    _, err_b = b.communicate(timeout=120)
    assert a.returncode == -signal.SIGKILL
    lines = err_b.strip().splitlines()
    assert b.returncode == 128 + signal.SIGINT and len(lines) == 1 and lines[0].startswith("pmsr: "), err_b
    assert len(blocks(tmp_path / "bank")) < 12
    again = [pmsr(args, tmp_path) for _ in range(2)]  # the same command, on both cores again
    for p in again:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
    assert blocks(tmp_path / "bank") == [f"block-{k:04d}" for k in range(12)]
    assert not list((tmp_path / "bank").glob(".*claim*"))
    finish(["merge", "bank", "--out", "merged"], tmp_path)
    assert figures(tmp_path / "merged" / "results.json") == reference(tmp_path_factory.getbasetemp(), 12)


def children(pid: int) -> list[int]:
    """The PIDs of ``pid``'s child processes (Linux /proc)."""
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text().split()
        out.extend(int(t) for t in text)
    return out


def running_in(folder: Path) -> list[int]:
    """PIDs of the processes with ``folder`` on their command line."""
    out = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            if str(folder).encode() in (proc / "cmdline").read_bytes():
                out.append(int(proc.name))
        except OSError:
            continue
    return out


@pytest.mark.slow
def test_the_local_executor_killed_leaves_nothing_and_reruns_to_the_same_figures(tmp_path, tmp_path_factory):
    pytest.importorskip("submitit")
    scenario(tmp_path, 8)
    args = ["evaluate", "sc.yaml", "--out", "ev", "--executor", "local", "--shards", "2", "--quiet"]
    p = pmsr(args, tmp_path)
    deadline = time.time() + 120
    while len(children(p.pid)) < 2 and p.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    workers = children(p.pid)
    assert p.poll() is None and workers, "no worker process appeared"
    time.sleep(rng.uniform(0.5, 1.5))
    os.kill(workers[0], signal.SIGKILL)
    time.sleep(0.2)
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    lines = err.strip().splitlines()
    assert p.returncode != 0 and len(lines) == 1, err
    assert lines[0].startswith(("pmsr: error: shard 1/2", "pmsr: error: shard 2/2", "pmsr: interrupted by SIGINT")), err
    assert not [pid for pid in running_in(tmp_path)]  # no worker lives on (an orphan would write on)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["sc.yaml"]  # no output, no staging folder
    finish(args, tmp_path)
    assert figures(tmp_path / "ev" / "results.json") == reference(tmp_path_factory.getbasetemp(), 8)


# -- disk full ---------------------------------------------------------------------------------------

DRIVER = textwrap.dedent("""\
    # runs inside `unshare -rm`: a private mount namespace, so the tmpfs vanishes with the process;
    # pmsr runs in-process (one import of torch for both commands)
    import contextlib, hashlib, io, json, os, shutil, subprocess, sys
    mnt, margin_kb, size_kb, earlier = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", mnt], check=True)
    os.chdir(mnt)
    shutil.copy(os.path.join(earlier, "sc.yaml"), "sc.yaml")
    shutil.copytree(os.path.join(earlier, "ev"), "earlier")  # an earlier result on the same disk
    from pmsr_nn.cli import main

    def state():
        out = {}
        for folder, _, files in os.walk("."):
            for name in files:
                path = os.path.relpath(os.path.join(folder, name))
                if path != "filler":
                    out[path] = hashlib.sha256(open(path, "rb").read()).hexdigest()
        return out

    st = os.statvfs(".")
    with open("filler", "wb") as f:  # leave margin_kb free
        f.write(b"\\0" * max(st.f_bavail * st.f_frsize - margin_kb * 1024, 0))
    before = state()
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(["evaluate", "sc.yaml", "--out", "later", "--quiet"])
    after = state()
    print(json.dumps({"rc": rc, "stderr": err.getvalue(), "before": before, "after": after,
                      "names": sorted(os.listdir("."))}))
""")


def full_disk_run(tmp_path: Path, margin_kb: int) -> dict:
    """``pmsr evaluate`` on a 3 MiB tmpfs with ``margin_kb`` free, after an earlier result on it."""
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-rm", "true"], capture_output=True).returncode:
        pytest.skip("no private mount namespace here (unshare -rm): cannot fill a disk of our own")
    from pmsr_nn.cli import main

    mnt = tmp_path / "mnt"
    mnt.mkdir()
    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER)
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    assert main(["evaluate", str(scenario(earlier, 4, block_runs=2)), "--out", str(earlier / "ev"), "--quiet"]) == 0
    p = subprocess.run(["unshare", "-rm", sys.executable, str(driver), str(mnt), str(margin_kb), "3072", str(earlier)],
                       capture_output=True, text=True, env=ENV, timeout=300)
    if p.returncode and "mount" in p.stderr and "CalledProcessError" in p.stderr:
        pytest.skip(f"tmpfs cannot be mounted here: {p.stderr.strip().splitlines()[-1]}")
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


def check_full_disk(res: dict) -> None:
    lines = res["stderr"].strip().splitlines()
    assert res["rc"] == 2 and lines == ["pmsr: error: no space left on the device"], res["stderr"]
    assert res["after"] == res["before"]  # the earlier results byte for byte, nothing new (half-written or not)
    assert res["names"] == ["earlier", "filler", "sc.yaml"]
    assert any(k.startswith("earlier/") and k.endswith("results.json") for k in res["before"])


@pytest.mark.integration
def test_a_disk_that_fills_mid_evaluate_is_one_line_and_loses_nothing(tmp_path):
    check_full_disk(full_disk_run(tmp_path, 60))


@pytest.mark.slow
@pytest.mark.parametrize("margin_kb", [4, 16, 40, 100])
def test_a_disk_that_fills_at_any_stage_of_evaluate_is_one_line_and_loses_nothing(tmp_path, margin_kb):
    check_full_disk(full_disk_run(tmp_path, margin_kb))
