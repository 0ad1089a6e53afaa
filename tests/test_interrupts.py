"""Kill ``pmsr simulate``, ``evaluate`` and ``train`` at a random time (SIGINT, SIGTERM, SIGKILL).

After a catchable signal: exit code 128 + signal, one line on stderr, and no partial output; a
run with a checkpoint is kept and says how to resume. After SIGKILL: at most a hidden
``.NAME.partial-PID`` folder, which the next run removes. Either way the rerun (or the resume)
gives results identical to an uninterrupted run. The kill time is drawn at random (seeded)
after the command has started writing, so each signal lands somewhere in the real work.
"""

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGKILL]
rng = random.Random(20261123)


def pmsr(args, cwd):
    return subprocess.Popen([sys.executable, "-m", "pmsr_nn.cli", *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)})


def finish(args, cwd, timeout=600):
    p = pmsr(args, cwd)
    out, err = p.communicate(timeout=timeout)
    assert p.returncode == 0, err
    return out


def kill_when(p, started, sig, extra_s):
    """Send ``sig`` ``extra_s`` seconds after ``started()`` first holds; return (rc, stderr)."""
    deadline = time.time() + 120
    while not started() and p.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    assert p.poll() is None, f"the command ended before it could be interrupted: {p.communicate()}"
    time.sleep(extra_s)
    assert p.poll() is None, "the command ended before the signal: make it longer"
    p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    return p.returncode, err


def partials(folder):
    return sorted(p.name for p in Path(folder).iterdir() if ".partial-" in p.name or ".old-" in p.name)


def check_stopped(rc, err, sig, kept=None):
    if sig == signal.SIGKILL:
        assert rc == -signal.SIGKILL
        return
    lines = err.strip().splitlines()
    assert rc == 128 + sig and len(lines) == 1, err
    assert lines[0].startswith(f"pmsr: interrupted by {signal.Signals(sig).name}; ")
    assert (kept or "no partial output was left behind") in lines[0]


def interrupt_writing(cwd: Path, argv: list[str], out: str, sig, delay: tuple[float, float]) -> int:
    """Start ``pmsr ARGV --out OUT``, send ``sig`` a random time after its temporary folder
    appears, check how it stopped and that ``OUT`` does not exist; return the process id."""
    p = pmsr([*argv, "--out", out, "--quiet"], cwd)
    rc, err = kill_when(p, lambda: any(f".{out}.partial-" in n.name for n in cwd.iterdir()), sig, rng.uniform(*delay))
    check_stopped(rc, err, sig)
    assert not (cwd / out).exists()
    return p.pid


def checksums(dataset):
    return json.loads((Path(dataset) / "manifest.json").read_text())["checksums_sha256"]


@pytest.fixture(scope="module")
def recipe(tmp_path_factory):
    root = tmp_path_factory.mktemp("sim")
    raw = yaml.safe_load((ROOT / "datasets/fitee2023_ca.yaml").read_text())
    raw["tracks"] = 30_000  # about 5 s of work on a 2-core CPU
    (root / "r.yaml").write_text(yaml.safe_dump(raw))
    finish(["simulate", "r.yaml", "--out", "reference", "--quiet"], root)
    return root


@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_simulate_killed_at_random_leaves_nothing_and_reruns_identically(recipe, sig):
    cwd = recipe
    pid = interrupt_writing(cwd, ["simulate", "r.yaml"], "ds", sig, (0.2, 1.5))
    assert partials(cwd) == ([] if sig != signal.SIGKILL else [f".ds.partial-{pid}"])
    finish(["simulate", "r.yaml", "--out", "ds", "--quiet"], cwd)
    assert partials(cwd) == [] and checksums(cwd / "ds") == checksums(cwd / "reference")
    finish(["simulate", "r.yaml", "--out", "ds", "--overwrite", "--quiet"], cwd)  # replaced whole, nothing aside
    assert partials(cwd) == [] and checksums(cwd / "ds") == checksums(cwd / "reference")
    import shutil

    shutil.rmtree(cwd / "ds")


def scenario(root: Path, mc_runs: int) -> Path:
    d = {"name": "kill", "seed": 5, "mc_runs": mc_runs, "block_runs": 2, "warmup_steps": 100,
         "cases": [{"name": "t1", "start_range_m": 4000.0, "start_bearing_deg": 130.0, "speed_mps": 10.0,
                    "heading_deg": 20.0, "segments": [{"duration_s": 300.0}]}],
         "methods": [{"name": "EKF", "kind": "ekf"}, {"name": "UKF", "kind": "ukf"}, {"name": "PF", "kind": "particle_filter"}]}
    (root / "sc.yaml").write_text(yaml.safe_dump(d))
    return root / "sc.yaml"


def accuracy(results: Path) -> dict:
    res = json.loads(results.read_text())
    return {c: {m: {k: v for k, v in r.items() if k != "seconds_per_run"} for m, r in v["methods"].items()}
            for c, v in res["cases"].items()}


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval")
    scenario(root, 40)
    finish(["evaluate", "sc.yaml", "--out", "reference", "--quiet"], root)
    return root


@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_evaluate_killed_at_random_leaves_nothing_and_reruns_identically(evaluation, sig):
    cwd = evaluation
    interrupt_writing(cwd, ["evaluate", "sc.yaml"], "ev", sig, (0.5, 2.0))
    finish(["evaluate", "sc.yaml", "--out", "ev", "--quiet"], cwd)
    assert partials(cwd) == []
    assert accuracy(cwd / "ev" / "results.json") == accuracy(cwd / "reference" / "results.json")
    import shutil

    shutil.rmtree(cwd / "ev")


TRAIN = ["trainer.progress=false", "trainer.max_epochs=14", "trainer.early_stopping_patience=null",
         "trainer.checkpoint_every_n_steps=8", "trainer.threads=1"]


def same_training(a: Path, b: Path) -> bool:
    """Equal final weights (last.ckpt, not the best, which may predate the kill), and the
    resumed run's validation history (the epochs after the resume) equal to the end of ``a``'s."""
    wa = torch.load(a / "checkpoints" / "last.ckpt", weights_only=True)["state_dict"]
    wb = torch.load(b / "checkpoints" / "last.ckpt", weights_only=True)["state_dict"]
    ha = [r["val_pos_rmse_m"] for r in json.loads((a / "metrics.json").read_text())["history"]]
    hb = [r["val_pos_rmse_m"] for r in json.loads((b / "metrics.json").read_text())["history"]]
    return wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa) and 0 < len(hb) and hb == ha[-len(hb):]


@pytest.fixture(scope="module")
def training(tmp_path_factory):
    root = tmp_path_factory.mktemp("train")
    (root / "smoke.yaml").write_text((ROOT / "train/smoke.yaml").read_text())
    finish(["train", "smoke.yaml", "--out", "reference", *TRAIN], root)
    return root


@pytest.mark.parametrize("sig", SIGNALS, ids=lambda s: signal.Signals(s).name)
def test_train_killed_after_a_checkpoint_resumes_to_identical_weights(training, sig):
    cwd, run = training, f"run-{signal.Signals(sig).name}"
    last = cwd / run / "checkpoints" / "last.ckpt"
    p = pmsr(["train", "smoke.yaml", "--out", run, *TRAIN], cwd)
    rc, err = kill_when(p, last.is_file, sig, rng.uniform(0.0, 2.0))
    check_stopped(rc, err, sig, kept=f"continue it with 'pmsr train --resume --out {run}'")
    assert not (cwd / run / "metrics.json").exists()  # really cut short
    step = torch.load(last, weights_only=True)["global_step"]
    total = json.loads((cwd / "reference" / "metrics.json").read_text())["global_step"]
    assert 0 < step < total  # checkpoints every 8 steps of 24-batch epochs: mostly mid-epoch
    finish(["train", "--resume", "--out", run], cwd)
    assert same_training(cwd / "reference", cwd / run)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_train_interrupted_before_its_first_checkpoint_leaves_no_folder(training, sig):
    cwd = training
    p = pmsr(["train", "smoke.yaml", "--out", "early", *TRAIN, "trainer.checkpoint_every_n_steps=100000"], cwd)
    rc, err = kill_when(p, lambda: (cwd / "early" / "config.yaml").is_file(), sig, 0.0)
    check_stopped(rc, err, sig)
    assert not (cwd / "early").exists()


def test_train_killed_before_its_first_checkpoint_starts_afresh_on_resume(training):
    cwd = training
    p = pmsr(["train", "smoke.yaml", "--out", "fresh", *TRAIN], cwd)
    rc, _ = kill_when(p, lambda: (cwd / "fresh" / "config.yaml").is_file(), signal.SIGKILL, 0.0)
    assert rc == -signal.SIGKILL and not (cwd / "fresh" / "checkpoints" / "last.ckpt").exists()
    finish(["train", "--resume", "--out", "fresh"], cwd)
    assert same_training(cwd / "reference", cwd / "fresh")
