"""Shared fixtures and per-case sandboxes for the fault catalogue (``tests/faults/cases.py``).

The fixtures are built ONCE, with the ``pmsr`` command of the checkout under test, into a cache
folder; every case then gets a fresh copy of them. Layout of a sandbox::

    BOX/outside.txt          a user's file next to the working folder (what ``--out ..`` must not eat)
    BOX/work/                the working folder (cwd of the command); a copy of the fixtures:
        user/                the user's own files: notes.txt, data.csv, sub/deep.txt, sub/blob.bin, empty/
        recipe.yaml          a tiny valid recipe (12 tracks x 120 steps, window 20)
        recipe_big.yaml      a recipe that simulates for a while (signal cases)
        train.yaml           a tiny valid training config on ``ds`` (trains in seconds)
        train_long.yaml      the same with a long budget (signal cases)
        sc.yaml              a tiny single-target scenario (EKF + UKF, 4 runs in 2 blocks of 2)
        sc_learned.yaml      sc.yaml plus a learned method on run/tracker.pt
        sc_big.yaml          a scenario that runs for minutes (signal cases)
        ds/                  ``pmsr simulate recipe.yaml --out ds``
        z.csv                ``pmsr export ds --out z.csv --tracks 2``
        run/                 ``pmsr train train.yaml --out run`` (tracker.pt, checkpoints/last.ckpt)
        shard1/, shard2/     ``pmsr evaluate sc.yaml --shard 1/2`` and ``2/2``
        ev/                  ``pmsr evaluate sc.yaml --out ev`` (a complete evaluation)
        bank/                ``pmsr evaluate sc.yaml --out bank --per-block`` (bank.json, block-0000, block-0001)

Only the standard library is imported here (PyYAML is optional: the configs are written as text).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

FIXTURE_FORMAT = 5
"""Bump when the fixtures change: the cache key includes it."""

USER_FILES = {
    "user/notes.txt": "My field notes: receiver 2 was moved on 2024-05-03. Do not lose this.\n",
    "user/data.csv": "a,b,c\n1,2,3\n4,5,6\n",
    "user/sub/deep.txt": "a file deep inside the user's folder\n",
}
USER_BINARY = {"user/sub/blob.bin": bytes(range(256)) * 64}
USER_DIRS = ("user/empty",)
OUTSIDE_FILE = ("outside.txt", "a user's file next to the working folder\n")

RECIPE_YAML = """\
# tiny recipe for the fault census: the built-in FITEE 2023 CA recipe, shortened
name: tiny
seed: 0
tracks: 12
variant: envelope
dim: 2
window: 20
motion:
  dt_s: 1.0
  steps: 120
noise:
  range_m: [16.0, 30.0]
  range_rate_mps: [2.0, 4.0]
  azimuth_deg: [0.6, 3.0]
splits: {train: 0.8, val: 0.1, test: 0.1}
"""

RECIPE_BIG_YAML = """\
# a recipe that takes a while to simulate (signal cases)
name: big
seed: 1
tracks: 4000
variant: envelope
window: 100
motion:
  steps: 1000
storage:
  chunk_tracks: 64
"""

TRAIN_YAML = """\
# tiny training config for the fault census: trains in seconds on ds
name: tiny
seed: 0
data:
  path: ds
  batch_size: 16
  eval_window_stride: 5
model:
  kind: mdfnn
  hidden: [16, 16]
  filter_order: 4
optim:
  lr: 0.003
  schedule: cosine
trainer:
  max_epochs: 2
  train_batches_per_epoch: 3
  val_batches: 2
  accelerator: cpu
  early_stopping_patience: null
  checkpoint_every_n_steps: 2
  log_every_n_steps: 1
  progress: false
  threads: 1
"""

TRAIN_LONG_YAML = TRAIN_YAML.replace("max_epochs: 2", "max_epochs: 2000").replace(
    "train_batches_per_epoch: 3", "train_batches_per_epoch: 40").replace("name: tiny", "name: long")

SCENARIO_YAML = """\
# tiny single-target scenario for the fault census (classical methods only)
name: tiny
seed: 3
mc_runs: 4
block_runs: 2
warmup_steps: 20
noise: {range_m: 30.0, range_rate_mps: 2.0, azimuth_deg: 3.0}
cases:
  - name: steady
    start_range_m: 4000.0
    start_bearing_deg: 130.0
    speed_mps: 10.0
    heading_deg: 20.0
    segments:
      - {duration_s: 60.0}
methods:
  - {name: EKF, kind: ekf}
  - {name: UKF, kind: ukf}
"""

SCENARIO_LEARNED_YAML = SCENARIO_YAML.replace("name: tiny", "name: tiny_learned") + \
    "  - {name: MDFNN, kind: learned, checkpoint: run/tracker.pt}\n"

SCENARIO_BIG_YAML = """\
# a scenario that runs for minutes (signal cases)
name: big
seed: 0
mc_runs: 400
block_runs: 10
warmup_steps: 100
cases:
  - name: steady
    start_range_m: 4000.0
    start_bearing_deg: 130.0
    speed_mps: 10.0
    heading_deg: 20.0
    segments:
      - {duration_s: 1000.0}
methods:
  - {name: EKF, kind: ekf}
  - {name: PF, kind: particle_filter, options: {particles: 3000}}
"""

TEXT_FILES = {
    "recipe.yaml": RECIPE_YAML,
    "recipe_big.yaml": RECIPE_BIG_YAML,
    "train.yaml": TRAIN_YAML,
    "train_long.yaml": TRAIN_LONG_YAML,
    "sc.yaml": SCENARIO_YAML,
    "sc_learned.yaml": SCENARIO_LEARNED_YAML,
    "sc_big.yaml": SCENARIO_BIG_YAML,
}

BUILD_STEPS: tuple[tuple[tuple[str, ...], ...], ...] = (
    # steps of one inner tuple run concurrently; the groups run in order
    (("simulate", "recipe.yaml", "--out", "ds", "--quiet"),),
    (("export", "ds", "--out", "z.csv", "--tracks", "2"),
     ("evaluate", "sc.yaml", "--out", "shard1", "--shard", "1/2", "--quiet")),
    (("train", "train.yaml", "--out", "run"),
     ("evaluate", "sc.yaml", "--out", "shard2", "--shard", "2/2", "--quiet")),
    (("evaluate", "sc.yaml", "--out", "ev", "--quiet"),
     ("evaluate", "sc.yaml", "--out", "bank", "--per-block", "--quiet")),
)
EXPECTED = ("ds/manifest.json", "ds/tracks.h5", "z.csv", "run/tracker.pt", "run/checkpoints/last.ckpt",
            "run/config.yaml", "shard1/shard.json", "shard1/blocks.npz", "shard2/shard.json", "shard2/blocks.npz",
            "ev/results.json", "bank/bank.json", "bank/block-0000/blocks.npz", "bank/block-0001/blocks.npz")


# -- running the command of a checkout --------------------------------------------------------

def default_python() -> str:
    """The interpreter that runs ``pmsr`` (this one: the project's .venv)."""
    return sys.executable


def pmsr_env(pmsr_root: str | Path, cache_dir: str | Path | None = None) -> dict[str, str]:
    """Environment for ``python -m pmsr_nn.cli`` with ``pmsr_root``'s code first on the path.

    Byte-code goes to a private prefix (the checkout is never written), matplotlib's cache to the
    cache folder, progress bars are off (they are not part of the error path under test).
    """
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(pmsr_root).resolve()), *filter(None, [env.get("PYTHONPATH")])])
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    env["MPLBACKEND"] = "Agg"
    env["TQDM_DISABLE"] = "1"
    env["PYTHONUNBUFFERED"] = "1"
    env["CUDA_VISIBLE_DEVICES"] = ""
    env.pop("PMSR_TRAIN_RUN", None)
    if cache_dir is not None:
        cache = Path(cache_dir)
        env["PYTHONPYCACHEPREFIX"] = str(cache / "pycache")
        env.pop("PYTHONDONTWRITEBYTECODE")
        env["MPLCONFIGDIR"] = str(cache / "mplconfig")
    return env


def pmsr_command(argv, python: str | None = None) -> list[str]:
    return [python or default_python(), "-m", "pmsr_nn.cli", *argv]


def source_digest(pmsr_root: str | Path) -> str:
    """SHA-256 over the checkout's package sources (the fixture cache key)."""
    h = hashlib.sha256(f"format {FIXTURE_FORMAT}\n".encode())
    for text in TEXT_FILES.values():
        h.update(text.encode())
    pkg = Path(pmsr_root).resolve() / "pmsr_nn"
    for p in sorted(pkg.rglob("*")):
        if p.is_file() and p.suffix in (".py", ".yaml", ".json") and "__pycache__" not in p.parts:
            h.update(str(p.relative_to(pkg)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def write_user_files(root: Path) -> None:
    for rel, text in USER_FILES.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    for rel, data in USER_BINARY.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    for rel in USER_DIRS:
        (root / rel).mkdir(parents=True, exist_ok=True)


def build_fixtures(cache_dir: str | Path, pmsr_root: str | Path, python: str | None = None, log=print,
                   run=None) -> Path:
    """Build (once) the fixture working folder for ``pmsr_root`` under ``cache_dir``; return it.

    ``run(argv, work) -> (exit code, output)``: how a step runs when given (the tests: in-process,
    one step after another, sparing a Python start-up per step); default: ``pmsr_root``'s
    command as subprocesses, the steps of a group side by side.

    The folder is keyed by a digest of the checkout's sources; a complete build is marked by a
    ``.complete`` stamp next to it, so a later call returns at once.
    """
    cache_dir = Path(cache_dir).resolve()
    key = source_digest(pmsr_root)
    home = cache_dir / f"fixtures-{key}"
    work = home / "work"
    stamp = home / ".complete"
    if stamp.is_file() and work.is_dir():
        return work
    if home.exists():
        rmtree_force(home)
    work.mkdir(parents=True)
    write_user_files(work)
    for name, text in TEXT_FILES.items():
        (work / name).write_text(text)
    env = pmsr_env(pmsr_root, cache_dir)
    t0 = time.perf_counter()
    for group in BUILD_STEPS:
        if run is not None:
            for argv in group:
                rc, output = run(list(argv), work)
                if rc != 0:
                    raise RuntimeError(f"fixture step 'pmsr {' '.join(argv)}' failed with exit code {rc}:\n{output[-3000:]}")
            log(f"fixtures: {' ; '.join('pmsr ' + ' '.join(a) for a in group)}  ({time.perf_counter() - t0:.0f} s)")
            continue
        procs = []
        for argv in group:
            logf = open(home / f"build-{argv[0]}-{len(list(home.glob('build-*')))}.log", "w")
            procs.append((argv, subprocess.Popen(pmsr_command(argv, python), cwd=work, env=env,
                                                 stdin=subprocess.DEVNULL, stdout=logf, stderr=subprocess.STDOUT),
                          logf))
        for argv, p, logf in procs:
            rc = p.wait(timeout=600)
            logf.close()
            if rc != 0:
                raise RuntimeError(f"fixture step 'pmsr {' '.join(argv)}' failed with exit code {rc}; "
                                   f"see {logf.name}:\n{Path(logf.name).read_text()[-3000:]}")
        log(f"fixtures: {' ; '.join('pmsr ' + ' '.join(a) for a in group)}  ({time.perf_counter() - t0:.0f} s)")
    missing = [rel for rel in EXPECTED if not (work / rel).exists()]
    if missing:
        raise RuntimeError(f"fixture build did not produce {missing}")
    stamp.write_text(f"{key}\n{Path(pmsr_root).resolve()}\n")
    return work


def make_sandbox(fixtures: str | Path, dest: str | Path) -> Path:
    """A fresh copy of the fixtures under ``dest/box/work``; returns the working folder."""
    box = Path(dest) / "box"
    if box.exists():
        rmtree_force(box)
    box.mkdir(parents=True)
    (box / OUTSIDE_FILE[0]).write_text(OUTSIDE_FILE[1])
    work = box / "work"
    shutil.copytree(fixtures, work, symlinks=True)
    return work


# -- what changed ----------------------------------------------------------------------------

def _sha256(path: str) -> str:
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    except OSError as exc:
        return f"unreadable:{exc.errno}"
    return h.hexdigest()


def snapshot(root: str | Path) -> dict[str, str]:
    """``relative path -> 'dir' | 'link:TARGET' | sha256 | 'other'`` for everything under ``root``
    (symbolic links are recorded, never followed)."""
    root = Path(root)
    out: dict[str, str] = {}
    if not root.exists():
        return out
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        rel_dir = os.path.relpath(dirpath, root)
        for name in list(dirnames):
            full = os.path.join(dirpath, name)
            rel = os.path.normpath(os.path.join(rel_dir, name))
            if os.path.islink(full):
                out[rel] = f"link:{os.readlink(full)}"
                dirnames.remove(name)
            else:
                out[rel] = "dir"
        for name in filenames:
            full = os.path.join(dirpath, name)
            rel = os.path.normpath(os.path.join(rel_dir, name))
            st = os.lstat(full)
            if stat.S_ISLNK(st.st_mode):
                out[rel] = f"link:{os.readlink(full)}"
            elif stat.S_ISREG(st.st_mode):
                out[rel] = _sha256(full)
            else:
                out[rel] = "other"
    return out


def diff_snapshots(before: dict[str, str], after: dict[str, str]) -> dict[str, list[str]]:
    """Paths created, removed and modified (content, or kind: file/dir/link) between two snapshots."""
    created = sorted(set(after) - set(before))
    removed = sorted(set(before) - set(after))
    modified = sorted(p for p in set(before) & set(after) if before[p] != after[p])
    return {"created": created, "removed": removed, "modified": modified}


def rmtree_force(path: str | Path) -> None:
    """Remove a sandbox even where a case made folders read-only (never follows links)."""
    path = Path(path)

    def onerror(func, p, exc_info):
        try:
            parent = os.path.dirname(p)
            os.chmod(parent, 0o700)
            if os.path.isdir(p) and not os.path.islink(p):
                os.chmod(p, 0o700)
            func(p)
        except OSError:
            pass

    if path.is_symlink():
        path.unlink()
        return
    if path.exists():
        for dirpath, dirnames, _ in os.walk(path, followlinks=False):
            for d in dirnames:
                full = os.path.join(dirpath, d)
                if not os.path.islink(full):
                    try:
                        os.chmod(full, 0o700)
                    except OSError:
                        pass
        shutil.rmtree(path, onerror=onerror)
