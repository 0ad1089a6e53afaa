"""The fault catalogue of issue "Nothing lost, nothing hangs, one error path".

Every :class:`Case` is one bad input or fault for one ``pmsr`` command, as plain data: the
arguments (relative paths inside a sandbox, see :mod:`.sandbox`), a ``setup`` that makes the bad
input inside the sandbox's working folder, the paths the command may write (``outputs``) and what
a careful package SHOULD do (``expect``): ``"refuse"`` (exit code 2, one stderr line
``pmsr: error: ...``, nothing changed, nothing left behind) or ``"ok"`` (exit code 0, nothing
outside ``outputs`` changed). ``benchmarks/fault_census.py`` runs them as subprocesses; a pytest
suite can run the same cases in-process.

Conventions:

* ``outputs`` are paths the command may create or replace *when it succeeds*. For a case that
  must refuse, everything that existed before must be unchanged, outputs included, and nothing
  new may remain (a signal case may keep what it declares in ``outputs``, e.g. the checkpoint of
  an interrupted training run).
* ``message``: a substring of the one error line of a refusal; of stderr (a warning) for an
  ``ok`` case.
* ``signal``: ``("SIGTERM", 1.0)`` sends the signal 1 s after the first path matching one of
  ``signal_after`` (globs relative to the working folder; hidden names included) appears, or
  after ``signal_fallback`` s if none does. A signalled case must end with a non-zero exit code,
  one stderr line ``pmsr: ...``, and no ``.partial`` / ``.old-`` leftovers.
* ``root_expect``: the expectation that applies when the census runs as root, where permission
  bits are not enforced (a ``chmod 0o500`` folder is writable).
* ``verify`` (``ok`` cases): ``None`` when the output is right, else a short reason (the case
  then counts as a silent wrong answer).
* ``klass``: the issue's class the case illustrates (data_loss / hang / traceback / silent_wrong
  / refusal); it documents intent, the census measures the outcome.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .sandbox import RECIPE_YAML, SCENARIO_LEARNED_YAML, SCENARIO_YAML, TRAIN_YAML

COMMANDS = ("simulate", "info", "train", "select", "track", "export", "evaluate", "merge", "compare", "demo",
            "front-end")
DEFAULT_TIMEOUT = 60.0


@dataclass(frozen=True)
class Case:
    id: str                                   # unique, "command/slug"
    command: str                              # one of COMMANDS (the command the user meant)
    argv: tuple[str, ...]                     # arguments after `pmsr`, relative paths inside the sandbox
    expect: str                               # "refuse" or "ok"
    setup: Callable[[Path], None] | None = None
    outputs: tuple[str, ...] = ()
    message: str | None = None                # a substring of the (post-fix) error line (of the warning: "ok" cases)
    signal: tuple[str, float] | None = None   # (signal name, seconds after the trigger)
    timeout: float = DEFAULT_TIMEOUT
    klass: str = ""
    signal_after: tuple[str, ...] = ()        # globs that start the signal's clock when they appear
    signal_fallback: float = 40.0             # seconds after start when no signal_after path appears
    root_expect: str | None = None            # expectation when running as root
    verify: Callable[[Path], str | None] | None = None
    note: str = ""


# =============================================================================================
# setup helpers: each returns a function of the sandbox's working folder
# =============================================================================================

def steps(*fns: Callable[[Path], None]) -> Callable[[Path], None]:
    def run(root: Path) -> None:
        for f in fns:
            f(root)
    return run


def write(rel: str, text: str) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return f


def write_bytes(rel: str, data: bytes) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    return f


def mkdir(rel: str) -> Callable[[Path], None]:
    return lambda root: (root / rel).mkdir(parents=True, exist_ok=True)


def remove(rel: str) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        p = root / rel
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()
    return f


def symlink(rel: str, target: str) -> Callable[[Path], None]:
    """A symbolic link ``rel`` -> ``target`` (target as written: relative to the link's folder, or
    one of the fixed absolute system paths below)."""
    assert not target.startswith("/") or target in ("/sys", "/proc", "/dev/full"), target
    return lambda root: os.symlink(target, root / rel)


def chmod(rel: str, mode: int) -> Callable[[Path], None]:
    return lambda root: os.chmod(root / rel, mode)


def truncate(rel: str, keep: float = 0.5) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        p = root / rel
        data = p.read_bytes()
        p.write_bytes(data[: int(len(data) * keep)])
    return f


def copy(src: str, dst: str) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        if (root / src).is_dir():
            shutil.copytree(root / src, root / dst, symlinks=True)
        else:
            shutil.copyfile(root / src, root / dst)
    return f


def edit_json(rel: str, fn: Callable[[object], object]) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        p = root / rel
        data = json.loads(p.read_text())
        new = fn(data)
        p.write_text(json.dumps(data if new is None else new, indent=1))
    return f


def yaml_edit(src_text: str, dst: str, fn: Callable[[dict], None]) -> Callable[[Path], None]:
    """Load ``src_text`` (YAML), apply ``fn`` to the mapping, write it to ``dst``."""
    def f(root: Path) -> None:
        import yaml

        data = yaml.safe_load(src_text)
        fn(data)
        (root / dst).write_text(yaml.safe_dump(data, sort_keys=False))
    return f


def setkey(data: dict, dotted: str, value) -> None:
    node = data
    *path, last = dotted.split(".")
    for k in path:
        node = node.setdefault(k, {})
    node[last] = value


def yaml_set(src_text: str, dst: str, **dotted) -> Callable[[Path], None]:
    """``src_text`` with dotted keys (``__`` stands for ``.``) set, written to ``dst``."""
    def fn(data: dict) -> None:
        for k, v in dotted.items():
            setkey(data, k.replace("__", "."), v)
    return yaml_edit(src_text, dst, fn)


def text_sub(src_text: str, dst: str, old: str, new: str) -> Callable[[Path], None]:
    """``src_text`` with ``old`` replaced by ``new`` (exactly once), written to ``dst``."""
    assert src_text.count(old) == 1, old
    return write(dst, src_text.replace(old, new))


def alias_bomb(levels: int = 9, width: int = 9) -> str:
    """A YAML flow list whose last element expands to ``width ** levels`` leaves ("billion laughs")."""
    parts = ["&a0 [" + ", ".join(["lol"] * width) + "]"]
    for i in range(1, levels):
        parts.append(f"&a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]")
    return "[" + ", ".join(parts) + "]"


BOMB = alias_bomb()
DEEP = "[" * 20000 + "]" * 20000


def big_yaml(rel: str, head: str, mib: int = 50, key: str | None = None) -> Callable[[Path], None]:
    """``head`` followed by ``mib`` MiB of YAML: comment lines, or (``key``) one long list of numbers."""
    def f(root: Path) -> None:
        with open(root / rel, "w") as out:
            out.write(head)
            if key is None:
                line = "# " + "pasted log line, never meant to be here " * 4 + "\n"
                for _ in range((mib << 20) // len(line)):
                    out.write(line)
            else:
                out.write(f"{key}: [")
                chunk = "1.5, " * 20000
                for _ in range((mib << 20) // len(chunk)):
                    out.write(chunk)
                out.write("2.5]\n")
    return f


# -- CSV of measurements ------------------------------------------------------------------------

def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    rows = list(csv.reader(path.read_text().splitlines()))
    return rows[0], rows[1:]


def _csv_text(header: list[str] | None, rows: list[list[str]], newline: str = "\n") -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator=newline)
    if header is not None:
        w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def csv_edit(dst: str, fn: Callable[[list[str], list[list[str]]], tuple[list[str] | None, list[list[str]]]],
             src: str = "z.csv", newline: str = "\n", prefix: bytes = b"", encoding: str = "utf-8"):
    """``src`` (z.csv) transformed by ``fn(header, rows) -> (header, rows)`` and written to ``dst``."""
    def f(root: Path) -> None:
        header, rows = _read_csv(root / src)
        header, rows = fn(list(header), [list(r) for r in rows])
        (root / dst).write_bytes(prefix + _csv_text(header, rows, newline).encode(encoding))
    return f


def map_columns(prefix: str, fn: Callable[[float], float]):
    """An ``fn`` for :func:`csv_edit` applying ``fn`` to every column whose name starts with ``prefix``."""
    def edit(header, rows):
        cols = [i for i, h in enumerate(header) if h.startswith(prefix) and not h.startswith(prefix + "_rate")]
        for r in rows:
            for i in cols:
                r[i] = repr(fn(float(r[i])))
        return header, rows
    return edit


def set_cell(row: int, col: str, value: str):
    def edit(header, rows):
        rows[row][header.index(col)] = value
        return header, rows
    return edit


# -- checkpoints, datasets, shards ----------------------------------------------------------------

def torch_edit(src: str, dst: str, fn: Callable[[dict], object]) -> Callable[[Path], None]:
    """Load ``src`` (a pmsr checkpoint, plain data), apply ``fn`` (may return a replacement), save as ``dst``."""
    def f(root: Path) -> None:
        import torch

        blob = torch.load(root / src, map_location="cpu", weights_only=True)
        new = fn(blob)
        torch.save(blob if new is None else new, root / dst)
    return f


def _nan_weight(blob: dict) -> None:
    key = next(k for k, v in blob["state_dict"].items() if v.is_floating_point() and v.ndim == 2)
    blob["state_dict"][key].view(-1)[0] = float("nan")


def _nan_normalisation(blob: dict) -> None:
    blob["pmsr"]["normalisation"]["measurements"]["min"][0] = float("nan")


def _wrong_shape(blob: dict) -> None:
    import torch

    key = next(k for k, v in blob["state_dict"].items() if v.ndim == 2)
    w = blob["state_dict"][key]
    blob["state_dict"][key] = torch.zeros(w.shape[0] + 1, w.shape[1])


def _with_date(blob: dict) -> None:
    import datetime

    blob["pmsr"]["training"]["when"] = datetime.date(2024, 5, 3)


def _foreign(blob: dict):
    import torch

    return {"weights": torch.zeros(3), "epoch": 7}


class _Payload:
    """Unpickled, it would create the file PWNED in the working folder (it must never be unpickled)."""

    def __reduce__(self):
        return (open, ("PWNED", "w"))


def pickle_payload(rel: str) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        import torch

        torch.save({"state_dict": {}, "epoch": 1, "payload": _Payload()}, root / rel)
    return f


def h5_edit(rel: str, fn: Callable[[object], None]) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        import h5py

        with h5py.File(root / rel, "r+") as h5:
            fn(h5)
    return f


def _bump_measurement(h5) -> None:
    d = h5["measurements"]
    d[0, 0, 0] = d[0, 0, 0] + 1000.0


def _all_train(h5) -> None:
    h5["split"][...] = 0


def unsplit_copy(src: str, dst: str) -> Callable[[Path], None]:
    """A copy of dataset ``src`` as ``pmsr simulate --no-splits`` writes it: every track a test track (split
    codes, counts, recipe fractions and the split checksum rewritten; made without pmsr_nn, so a census of
    an older checkout gets the same input)."""
    def f(root: Path) -> None:
        import hashlib

        import h5py
        import numpy as np

        shutil.copytree(root / src, root / dst)
        m = json.loads((root / dst / "manifest.json").read_text())
        with h5py.File(root / dst / "tracks.h5", "r+") as h5:
            split = np.full(h5["split"].shape, 2, dtype=h5["split"].dtype)
            h5["split"][...] = split
            n = len(split)
            m["splits"] = {"train": 0, "val": 0, "test": n}
            m["windows"] = {"train": 0, "val": 0, "test": n * m["windows_per_track"]}
            m["recipe"]["splits"] = {"train": 0.0, "val": 0.0, "test": 1.0}
            m["checksums_sha256"]["split"] = hashlib.sha256(split.tobytes()).hexdigest()
            h5.attrs["manifest"] = json.dumps(m)
        (root / dst / "manifest.json").write_text(json.dumps(m, indent=2) + "\n")
    return f


def new_foreign_h5(rel: str) -> Callable[[Path], None]:
    """An HDF5 file at ``rel`` that is not a pmsr_nn dataset's (one dataset 'foo')."""
    def f(root: Path) -> None:
        import h5py

        with h5py.File(root / rel, "w") as h5:
            h5.create_dataset("foo", data=[1, 2, 3])
    return f


def foreign_h5(rel: str) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        import h5py

        (root / rel).unlink()
        with h5py.File(root / rel, "w") as h5:
            h5.create_dataset("foo", data=[1, 2, 3])
    return f


def npz_edit(rel: str, fn: Callable[[dict], dict]) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        import numpy as np

        with np.load(root / rel, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        arrays = fn(arrays)
        with open(root / rel, "wb") as out:
            np.savez(out, **arrays)
    return f


def _object_blocks(arrays: dict) -> dict:
    import numpy as np

    arrays["blocks"] = np.array([{"block": 1}], dtype=object)
    return arrays


def _no_blocks(arrays: dict) -> dict:
    arrays.pop("blocks")
    return arrays


def _move_receiver(m: dict) -> None:
    m["geometry"]["receivers"][0]["position_m"][0] += 750.0


# -- verifiers for ok cases ----------------------------------------------------------------------

def v_files(*rels: str) -> Callable[[Path], str | None]:
    def v(root: Path) -> str | None:
        missing = [r for r in rels if not (root / r).is_file()]
        return f"missing {missing}" if missing else None
    return v


def v_csv(rel: str, rows: int, finite: bool = True) -> Callable[[Path], str | None]:
    """A CSV of estimates with ``rows`` data rows of numbers, finite ones unless ``finite`` is false."""
    def v(root: Path) -> str | None:
        p = root / rel
        if not p.is_file():
            return f"{rel} missing"
        header, body = _read_csv(p)
        if len(body) != rows:
            return f"{rel}: {len(body)} rows, expected {rows}"
        for r in body if finite else ():
            for c in r[2:]:
                if not math.isfinite(float(c)):
                    return f"{rel}: non-finite value {c!r}"
        return None
    return v


def v_h5(rel: str) -> Callable[[Path], str | None]:
    def v(root: Path) -> str | None:
        import h5py
        import numpy as np

        if not (root / rel).is_file():
            return f"{rel} missing"
        with h5py.File(root / rel, "r") as h5:
            est = h5["estimates"][()]
        return None if np.isfinite(est).all() else f"{rel}: non-finite estimates"
    return v


def v_manifest(rel: str, dotted: str, value) -> Callable[[Path], str | None]:
    def v(root: Path) -> str | None:
        p = root / rel / "manifest.json"
        if not p.is_file():
            return f"{p.relative_to(root)} missing"
        node = json.loads(p.read_text())
        for k in dotted.split("."):
            node = node[k]
        return None if node == value else f"{dotted} = {node!r}, expected {value!r}"
    return v


def v_run(rel: str, dotted: str | None = None, value=None) -> Callable[[Path], str | None]:
    """A finished run (tracker.pt, metrics.json), optionally with a resolved config entry."""
    def v(root: Path) -> str | None:
        for f in ("tracker.pt", "metrics.json", "config.yaml"):
            if not (root / rel / f).is_file():
                return f"{rel}/{f} missing"
        if dotted is not None:
            import yaml

            node = yaml.safe_load((root / rel / "config.yaml").read_text())
            for k in dotted.split("."):
                node = node[k]
            if node != value:
                return f"{dotted} = {node!r}, expected {value!r}"
        return None
    return v


def v_results(rel: str, rows: tuple[str, ...] | None = None) -> Callable[[Path], str | None]:
    """A results.json with a finite position RMSE in every row (and, given ``rows``, exactly these rows per case)."""
    def v(root: Path) -> str | None:
        p = root / rel / "results.json"
        if not p.is_file():
            return f"{rel}/results.json missing"
        res = json.loads(p.read_text())
        if rows is not None:
            got = {c: sorted(per.get("methods", {})) for c, per in res.get("cases", {}).items()}
            if not got or any(names != sorted(rows) for names in got.values()):
                return f"rows {got}, expected {sorted(rows)} in every case"
        bad = [f"{c}/{m}" for c, per in res.get("cases", {}).items() for m, r in per.get("methods", {}).items()
               if not isinstance(r.get("rmse_pos_m"), (int, float)) or not math.isfinite(r["rmse_pos_m"])]
        return f"non-finite RMSE for {bad}" if bad else None
    return v


# =============================================================================================
# the catalogue
# =============================================================================================

CASES: list[Case] = []


def case(id: str, argv: str | tuple[str, ...] | list[str], expect: str = "refuse", **kw) -> Case:
    import shlex

    command = id.split("/", 1)[0]
    assert command in COMMANDS, id
    args = tuple(shlex.split(argv)) if isinstance(argv, str) else tuple(argv)
    c = Case(id=id, command=command, argv=args, expect=expect, **kw)
    CASES.append(c)
    return c


TRK = "track --checkpoint run/tracker.pt"
LOCK = symlink("locked", "/sys")              # a folder nobody may create files in, root included
RO = steps(mkdir("ro"), chmod("ro", 0o500))   # read-only for everyone but root
LINK_USER = symlink("link", "user")
FAKE_PNG = write_bytes("user/photo.png", b"\x89PNG\r\n\x1a\n" + b"my holiday photo" * 64)


def recipe_set(dst: str = "r.yaml", **dotted):
    return yaml_set(RECIPE_YAML, dst, **dotted)


def scenario_set(dst: str = "s.yaml", src: str = SCENARIO_YAML, **dotted):
    return yaml_set(src, dst, **dotted)


def scenario_method(dst: str, method: dict, src: str = SCENARIO_YAML):
    return yaml_edit(src, dst, lambda d: d["methods"].append(method))


def scenario_learned_options(dst: str, options: dict):
    def fn(d):
        d["methods"][-1]["options"] = options
    return yaml_edit(SCENARIO_LEARNED_YAML, dst, fn)


def train_set(dst: str = "t.yaml", **dotted):
    return yaml_set(TRAIN_YAML, dst, **dotted)


# ---------------------------------------------------------------------------------------------
# simulate
# ---------------------------------------------------------------------------------------------
SIM = "simulate recipe.yaml --quiet"

case("simulate/out-user-overwrite", f"{SIM} --out user --overwrite", message="user", klass="data_loss")
case("simulate/out-user-file-overwrite", f"{SIM} --out user/notes.txt --overwrite", message="notes.txt", klass="data_loss")
case("simulate/out-cwd-overwrite", f"{SIM} --out . --overwrite", message="out", klass="data_loss")
case("simulate/out-parent-overwrite", f"{SIM} --out .. --overwrite", message="out", klass="data_loss")
case("simulate/out-symlink-to-user-overwrite", f"{SIM} --out link --overwrite", setup=LINK_USER, message="link",
     klass="data_loss")
case("simulate/out-file-overwrite", f"{SIM} --out z.csv --overwrite", message="z.csv", klass="data_loss")
case("simulate/out-inside-file", f"{SIM} --out z.csv/x", message="z.csv", klass="traceback")
case("simulate/out-missing-parent-ok", f"{SIM} --out nope/new", "ok", outputs=("nope",),
     verify=v_manifest("nope/new", "recipe.tracks", 12), klass="refusal",
     note="every command creates missing parent folders (and removes them again when it fails)")
case("simulate/out-dataset-no-overwrite", f"{SIM} --out ds", message="--overwrite", klass="refusal")
case("simulate/out-dataset-overwrite-ok", f"{SIM} --out ds --overwrite", "ok", outputs=("ds",),
     verify=v_manifest("ds", "recipe.tracks", 12), klass="data_loss", note="replacing our own dataset is the documented use")
case("simulate/out-unwritable-sysfs", f"{SIM} --out locked/pmsr-census-new", setup=LOCK, message="locked",
     klass="traceback", note="locked -> /sys: no one may create files there, root included")
case("simulate/out-in-proc", f"{SIM} --out proc/pmsr-census-new", setup=symlink("proc", "/proc"),
     message="virtual file system with no disk behind it",
     klass="silent_wrong", note="was: '0.0 GB needed, 0.0 GB free (ask for fewer --tracks)'")
case("simulate/out-in-proc-subfolder", f"{SIM} --out proc/a/b", setup=symlink("proc", "/proc"),
     message="virtual file system with no disk behind it", klass="silent_wrong",
     note="the missing parents a/b are not created in /proc first")
case("simulate/out-in-sysfs", f"{SIM} --out sys/pmsr-census-new", setup=symlink("sys", "/sys"),
     message="virtual file system with no disk behind it", klass="traceback")
case("simulate/out-readonly-dir", f"{SIM} --out ro/new", setup=RO, outputs=("ro/new",), message="ro",
     root_expect="ok", klass="traceback")
case("simulate/recipe-missing", "simulate nope.yaml --out new", message="nope.yaml", klass="refusal")
case("simulate/recipe-is-directory", "simulate user --out new", message="user", klass="refusal")
case("simulate/recipe-unreadable", "simulate recipe.yaml --out new --quiet", setup=chmod("recipe.yaml", 0),
     outputs=("new",), root_expect="ok", message="recipe.yaml", klass="traceback")
case("simulate/recipe-invalid-yaml", "simulate bad.yaml --out new", setup=write("bad.yaml", "tracks: [1, 2\n"),
     message="yaml", klass="refusal")
case("simulate/recipe-empty-file", "simulate empty.yaml --out new", setup=write("empty.yaml", ""),
     message="empty.yaml", klass="refusal")
case("simulate/recipe-top-level-list", "simulate l.yaml --out new", setup=write("l.yaml", "- 1\n- 2\n"),
     message="mapping", klass="refusal")
case("simulate/recipe-non-utf8", "simulate r.yaml --out new",
     setup=write_bytes("r.yaml", RECIPE_YAML.encode() + "# réglage du récepteur\n".encode("latin-1")),
     message="utf-8", klass="traceback")
case("simulate/recipe-alias-bomb", "simulate r.yaml --out new",
     setup=text_sub(RECIPE_YAML, "r.yaml", "tracks: 12", f"tracks: {BOMB}"), message="alias", klass="hang")
case("simulate/recipe-million-numbers-for-an-interval", "simulate r.yaml --out new",
     setup=text_sub(RECIPE_YAML, "r.yaml", "range_m: [16.0, 30.0]", "range_m: [" + "16," * 999_999 + "30]"),
     message="noise.range_m (line 12) is a list of 1,000,000 values", klass="hang",
     note="counted in the text as it is refused; no alias in it, so no word of an alias bomb")
case("simulate/recipe-19000-numbers-for-an-interval", "simulate r.yaml --out new",
     setup=text_sub(RECIPE_YAML, "r.yaml", "range_m: [16.0, 30.0]", "range_m: [" + "16.0, " * 18_999 + "30.0]"),
     message="recipe.noise.range_m: expected 2 numbers, got 19,000", klass="refusal")
case("simulate/recipe-deep-nesting", "simulate r.yaml --out new",
     setup=text_sub(RECIPE_YAML, "r.yaml", "tracks: 12", f"tracks: {DEEP}"), message="r.yaml", klass="traceback")
case("simulate/recipe-50mb", "simulate r.yaml --out new", setup=big_yaml("r.yaml", RECIPE_YAML, 50, key="junk"),
     message="r.yaml", klass="hang", note="50 MB of numbers under an unknown key")
case("simulate/recipe-duplicate-key", "simulate r.yaml --out new --quiet",
     setup=write("r.yaml", RECIPE_YAML + "tracks: 24\n"), message="duplicate", klass="silent_wrong",
     note="PyYAML keeps the last of two equal keys without a word")
case("simulate/recipe-duplicate-receivers", "simulate r.yaml --out new --quiet",
     setup=recipe_set(geometry__receivers=[{"baseline_m": 7560.0, "bearing_deg": 240.0},
                                           {"baseline_m": 7560.0, "bearing_deg": 240.0},
                                           {"baseline_m": 8280.0, "bearing_deg": 300.0}]),
     message="receiver", klass="silent_wrong")
case("simulate/recipe-coincident-transmitters", "simulate r.yaml --out new --quiet",
     setup=recipe_set(geometry__transmitters=[{"position_m": [0.0, 0.0]}, {"position_m": [0.0, 0.0]}]),
     message="transmitter", klass="silent_wrong")
case("simulate/recipe-receiver-on-transmitter", "simulate r.yaml --out new",
     setup=recipe_set(geometry__receivers=[{"position_m": [0.0, 0.0]}]), message="receiver", klass="refusal")
case("simulate/recipe-receiver-position-and-baseline", "simulate r.yaml --out new",
     setup=recipe_set(geometry__receivers=[{"position_m": [-8000.0, 0.0], "baseline_m": 8000.0, "bearing_deg": 270.0}]),
     message="receiver", klass="refusal")
case("simulate/recipe-unknown-key", "simulate r.yaml --out new", setup=recipe_set(trackz=5), message="trackz",
     klass="refusal")
case("simulate/recipe-word-for-number", "simulate r.yaml --out new", setup=recipe_set(motion__q_psd="four"),
     message="q_psd", klass="refusal")
case("simulate/recipe-window-longer-than-track", "simulate r.yaml --out new", setup=recipe_set(window=500),
     message="window", klass="refusal")
case("simulate/recipe-nan-dt", "simulate r.yaml --out new",
     setup=text_sub(RECIPE_YAML, "r.yaml", "dt_s: 1.0", "dt_s: .nan"), message="dt_s", klass="refusal")
case("simulate/recipe-infinite-noise", "simulate r.yaml --out new",
     setup=text_sub(RECIPE_YAML, "r.yaml", "range_m: [16.0, 30.0]", "range_m: [16.0, .inf]"), message="range_m",
     klass="refusal")
case("simulate/recipe-negative-splits", "simulate r.yaml --out new",
     setup=recipe_set(splits={"train": 1.2, "val": -0.1, "test": -0.1}), message="split", klass="refusal")
case("simulate/recipe-chunk-zero", "simulate r.yaml --out new", setup=recipe_set(storage__chunk_tracks=0),
     message="chunk_tracks", klass="refusal")
case("simulate/recipe-negative-altitude", "simulate r.yaml --out new",
     setup=recipe_set(dim=3, motion__initial__altitude_m=[-10.0, 0.0]), message="altitude", klass="refusal")
case("simulate/recipe-impossible-envelope", "simulate r.yaml --out new --quiet",
     setup=recipe_set(envelope__range_m=[200.0, 201.0]), message="envelope", klass="hang",
     note="no track can stay inside a 1-m ring: the draws must give up with a clear error")
case("simulate/yaml-3e-3-ok", "simulate r.yaml --out new --quiet", "ok",
     setup=text_sub(RECIPE_YAML, "r.yaml", "dt_s: 1.0", "dt_s: 3e-3"), outputs=("new",),
     verify=v_manifest("new", "dt_s", 0.003), klass="silent_wrong", note="3e-3 is a float in YAML 1.2 and in every user's mind")
case("simulate/yaml-1e-7-ok", "simulate r.yaml --out new --quiet", "ok",
     setup=write("r.yaml", RECIPE_YAML + "envelope_variant:\n  q_psd: 1e-7\n"), outputs=("new",),
     verify=v_manifest("new", "recipe.envelope_variant.q_psd", 1e-7), klass="silent_wrong")
case("simulate/yaml-1E+9-ok", "simulate r.yaml --out new --quiet", "ok",
     setup=write("r.yaml", RECIPE_YAML + "geometry:\n  transmitters:\n    - {position_m: [0.0, 0.0], carrier_hz: 1E+9}\n"),
     outputs=("new",), verify=v_manifest("new", "recipe.geometry.transmitters", [{"position_m": [0.0, 0.0], "carrier_hz": 1e9}]),
     klass="silent_wrong")
case("simulate/yaml-dot5-ok", "simulate r.yaml --out new --quiet", "ok",
     setup=text_sub(RECIPE_YAML, "r.yaml", "splits: {train: 0.8, val: 0.1, test: 0.1}",
                    "splits: {train: .5, val: .25, test: .25}"),
     outputs=("new",), verify=v_manifest("new", "splits", {"train": 6, "val": 3, "test": 3}), klass="silent_wrong")
case("simulate/tracks-huge", f"{SIM} --out new --tracks 999999999999", message="tracks", klass="hang")
case("simulate/tracks-not-a-number", f"{SIM} --out new --tracks abc", message="--tracks", klass="refusal")
case("simulate/tracks-too-few-for-the-splits-ok", f"{SIM} --out new --tracks 3", "ok", outputs=("new",),
     verify=v_manifest("new", "splits", {"train": 0, "val": 0, "test": 3}), klass="refusal",
     note="a small dataset for tracking: every track a test track, not an error (issue 21)")
case("simulate/no-splits-ok", f"{SIM} --out new --no-splits", "ok", outputs=("new",),
     verify=v_manifest("new", "splits", {"train": 0, "val": 0, "test": 12}), klass="refusal")
case("simulate/recipe-empty-training-split", "simulate r.yaml --out new",
     setup=recipe_set(splits={"train": 0.0, "val": 0.5, "test": 0.5}), message="training split", klass="refusal")
case("simulate/seed-huge-ok", f"{SIM} --out new --seed 99999999999999999999", "ok", outputs=("new",),
     verify=v_manifest("new", "seed", 99999999999999999999), klass="refusal",
     note="seeds go through NumPy's SeedSequence: any non-negative integer is a valid seed")
case("simulate/variant-unknown", f"{SIM} --out new --variant loose", message="variant", klass="refusal")
case("simulate/typo-command", "simulat recipe.yaml --out new", message="simulat", klass="refusal")
case("simulate/unknown-option", f"{SIM} --out new --frobnicate", message="frobnicate", klass="refusal")
case("simulate/missing-out", "simulate recipe.yaml", message="out", klass="refusal")
_SIG_SIM = dict(argv="simulate recipe_big.yaml --out big --quiet", signal_after=(".big.partial*", "big"),
                klass="traceback")
case("simulate/sigterm", _SIG_SIM["argv"], signal=("SIGTERM", 2.0), signal_after=_SIG_SIM["signal_after"],
     klass="traceback", note="a killed simulate must not leave .big.partial-PID behind")
case("simulate/sighup", _SIG_SIM["argv"], signal=("SIGHUP", 2.0), signal_after=_SIG_SIM["signal_after"],
     klass="traceback", note="terminal closed")
case("simulate/sigint", _SIG_SIM["argv"], signal=("SIGINT", 2.0), signal_after=_SIG_SIM["signal_after"],
     klass="traceback", note="Ctrl-C")
case("simulate/sigterm-while-overwriting", "simulate recipe_big.yaml --out ds --overwrite --quiet",
     signal=("SIGTERM", 2.0), signal_after=(".ds.partial*",), klass="data_loss",
     note="the dataset being replaced must survive an interrupted overwrite")

# ---------------------------------------------------------------------------------------------
# info
# ---------------------------------------------------------------------------------------------
case("info/user-folder", "info user", message="user", klass="refusal")
case("info/missing", "info nope", message="nope", klass="refusal")
case("info/a-file", "info z.csv", message="z.csv", klass="refusal")
case("info/shard-folder", "info shard1", message="shard1", klass="refusal")
case("info/symlink-loop", "info loop", setup=symlink("loop", "loop"), message="loop", klass="refusal")
case("info/manifest-garbage", "info ds", setup=write("ds/manifest.json", "{not json"), message="manifest", klass="refusal")
case("info/manifest-json-list", "info ds", setup=write("ds/manifest.json", "[]\n"), message="ds", klass="refusal")
case("info/manifest-non-utf8", "info ds", setup=write_bytes("ds/manifest.json", b'{"format": "\xff\xfe"}'),
     message="manifest", klass="refusal")
case("info/manifest-is-directory", "info ds", setup=steps(remove("ds/manifest.json"), mkdir("ds/manifest.json")),
     message="manifest", klass="refusal")
case("info/manifest-without-envelope", "info ds", setup=edit_json("ds/manifest.json", lambda m: m.pop("envelope") and None),
     message="envelope", klass="traceback")
case("info/manifest-dt-is-text", "info ds", setup=edit_json("ds/manifest.json", lambda m: m.update(dt_s="1.0")),
     message="dt_s", klass="traceback")
case("info/manifest-shapes-not-mapping", "info ds", setup=edit_json("ds/manifest.json", lambda m: m.update(shapes="abc")),
     message="shapes", klass="traceback")
case("info/manifest-format-version", "info ds", setup=edit_json("ds/manifest.json", lambda m: m.update(format_version=99)),
     message="version", klass="refusal")
case("info/manifest-shape-mismatch", "info ds",
     setup=edit_json("ds/manifest.json", lambda m: m["shapes"]["states"].__setitem__(0, 13)), message="states",
     klass="refusal")
case("info/h5-missing", "info ds", setup=remove("ds/tracks.h5"), message="tracks.h5", klass="refusal")
case("info/h5-empty", "info ds", setup=write_bytes("ds/tracks.h5", b""), message="tracks.h5", klass="refusal")
case("info/h5-is-directory", "info ds", setup=steps(remove("ds/tracks.h5"), mkdir("ds/tracks.h5")),
     message="tracks.h5", klass="refusal")
case("info/h5-foreign", "info ds", setup=foreign_h5("ds/tracks.h5"), message="tracks.h5", klass="refusal")
case("info/h5-truncated-verify", "info ds --verify", setup=truncate("ds/tracks.h5", 0.6), message="tracks.h5",
     klass="traceback")
case("info/verify-corrupted-value", "info ds --verify", setup=h5_edit("ds/tracks.h5", _bump_measurement),
     message="checksum", klass="refusal")
case("info/verify-ok", "info ds --verify", "ok", klass="refusal")
case("info/dataset-without-splits-ok", "info small --verify", "ok", setup=unsplit_copy("ds", "small"), klass="traceback")
case("info/trailing-slash-ok", "info ds/", "ok", klass="refusal")
case("info/plot-ok", "info ds --plot fig.png", "ok", outputs=("fig.png",), verify=v_files("fig.png"), klass="refusal")
case("info/plot-over-user-file", "info ds --plot user/photo.png", setup=FAKE_PNG, message="photo.png", klass="data_loss")
case("info/plot-into-directory", "info ds --plot user", message="--plot", klass="traceback")
case("info/plot-unknown-extension", "info ds --plot fig.txt", message="fig.txt", klass="traceback")
case("info/plot-missing-parent", "info ds --plot nope/fig.png", message="nope", klass="traceback")
case("info/plot-inside-file", "info ds --plot z.csv/fig.png", message="z.csv", klass="traceback")
case("info/plot-disk-full", "info ds --plot full.png", setup=symlink("full.png", "/dev/full"), outputs=("full.png",),
     message="full.png", klass="traceback", note="full.png -> /dev/full: every write fails with ENOSPC")

# ---------------------------------------------------------------------------------------------
# train
# ---------------------------------------------------------------------------------------------
TR = "train train.yaml"

case("train/out-user", f"{TR} --out user", message="holds files that are not a training run", klass="data_loss")
case("train/out-user-file", f"{TR} --out user/notes.txt", message="notes.txt", klass="traceback")
case("train/out-inside-file", f"{TR} --out z.csv/run", message="z.csv", klass="traceback")
case("train/out-cwd", f"{TR} --out .", message="out", klass="data_loss")
case("train/out-symlink-to-user", f"{TR} --out link", setup=LINK_USER, message="link", klass="data_loss")
case("train/out-existing-run", f"{TR} --out run", message="--resume", klass="refusal")
case("train/out-unwritable-sysfs", f"{TR} --out locked/pmsr-run", setup=LOCK, message="locked", klass="traceback")
case("train/out-in-proc", f"{TR} --out proc/run", setup=symlink("proc", "/proc"),
     message="virtual file system with no disk behind it", klass="traceback",
     note="was: 'No such file or directory: proc/run' from deep inside the run")
case("train/out-readonly-dir", f"{TR} --out ro/run", setup=RO, outputs=("ro/run",), root_expect="ok", message="ro",
     klass="traceback")
case("train/ok", f"{TR} --out run2", "ok", outputs=("run2",), verify=v_run("run2"), klass="refusal")
case("train/ok-existing-empty-folder", f"{TR} --out empty", "ok", setup=mkdir("empty"), outputs=("empty",),
     verify=v_run("empty"), klass="refusal")
case("train/no-config", "train --out run2", message="config", klass="refusal")
case("train/overrides-without-config", "train trainer.max_epochs=1 --out run2", message="config", klass="refusal")
case("train/config-missing", "train nope.yaml --out run2", message="nope.yaml", klass="refusal")
case("train/config-is-directory", "train user --out run2", message="user", klass="refusal")
case("train/config-top-level-list", "train l.yaml --out run2", setup=write("l.yaml", "- 1\n"), message="mapping",
     klass="refusal")
case("train/config-non-utf8", "train t.yaml --out run2",
     setup=write_bytes("t.yaml", TRAIN_YAML.encode() + "# entraîné\n".encode("latin-1")), message="utf-8",
     klass="traceback")
case("train/config-alias-bomb", "train t.yaml --out run2",
     setup=text_sub(TRAIN_YAML, "t.yaml", "max_epochs: 2", f"max_epochs: {BOMB}"), message="alias", klass="hang")
case("train/config-deep-nesting", "train t.yaml --out run2",
     setup=text_sub(TRAIN_YAML, "t.yaml", "max_epochs: 2", f"max_epochs: {DEEP}"), message="t.yaml", klass="traceback")
case("train/config-duplicate-key", "train t.yaml --out run2",
     setup=text_sub(TRAIN_YAML, "t.yaml", "  max_epochs: 2\n", "  max_epochs: 2\n  max_epochs: 1\n"),
     outputs=("run2",), message="duplicate", klass="silent_wrong")
case("train/model-file-alias-bomb", "train t.yaml --out run2",
     setup=steps(write("m.yaml", f"kind: mdfnn\nhidden: [16, 16]\nfilter_order: {BOMB}\n"),
                 yaml_set(TRAIN_YAML, "t.yaml", model="m.yaml")), message="alias", klass="hang")
case("train/model-file-non-utf8", "train t.yaml --out run2",
     setup=steps(write_bytes("m.yaml", b"kind: mdfnn\nhidden: [16, 16]\nfilter_order: 4\n# \xe9t\xe9\n"),
                 yaml_set(TRAIN_YAML, "t.yaml", model="m.yaml")), message="utf-8", klass="traceback")
case("train/model-file-missing", "train t.yaml --out run2", setup=yaml_set(TRAIN_YAML, "t.yaml", model="nope.yaml"),
     message="nope.yaml", klass="refusal")
case("train/model-file-is-list", "train t.yaml --out run2",
     setup=steps(write("m.yaml", "- mdfnn\n"), yaml_set(TRAIN_YAML, "t.yaml", model="m.yaml")), message="m.yaml",
     klass="refusal")
case("train/override-not-key-value", f"{TR} --out run2 =5", message="=5", klass="refusal")
case("train/override-invalid-yaml", f"{TR} --out run2 trainer.max_epochs=[1", message="max_epochs", klass="refusal")
case("train/override-unknown-key", f"{TR} --out run2 trainer.max_epoch=1", message="max_epoch", klass="refusal")
case("train/override-section-by-scalar", f"{TR} --out run2 trainer=5", message="trainer", klass="refusal")
case("train/override-alias-bomb", ("train", "train.yaml", "--out", "run2", f"trainer.max_epochs={BOMB}"),
     message="alias", klass="hang")
case("train/yaml-3e-3-override-ok", f"{TR} --out run2 optim.lr=3e-3", "ok", outputs=("run2",),
     verify=v_run("run2", "optim.lr", 0.003), klass="silent_wrong")
case("train/yaml-1e-7-config-ok", "train t.yaml --out run2", "ok",
     setup=text_sub(TRAIN_YAML, "t.yaml", "  lr: 0.003\n", "  lr: 0.003\n  weight_decay: 1e-7\n"),
     outputs=("run2",), verify=v_run("run2", "optim.weight_decay", 1e-7), klass="silent_wrong")
case("train/yaml-dot5-override-ok", f"{TR} --out run2 optim.min_lr_ratio=.5", "ok", outputs=("run2",),
     verify=v_run("run2", "optim.min_lr_ratio", 0.5), klass="silent_wrong")
case("train/accelerator-gpu", f"{TR} --out run2 trainer.accelerator=gpu", message="accelerator", klass="traceback",
     note="no GPU on this machine")
case("train/accelerator-unknown", f"{TR} --out run2 trainer.accelerator=banana", message="accelerator", klass="traceback")
case("train/precision-unknown", f"{TR} --out run2 trainer.precision=banana", message="precision", klass="traceback")
case("train/strategy-unknown", f"{TR} --out run2 trainer.strategy=banana", message="strategy", klass="traceback")
case("train/devices-zero", f"{TR} --out run2 trainer.devices=0", message="devices", klass="refusal")
case("train/threads-negative", f"{TR} --out run2 trainer.threads=-1", message="threads", klass="traceback")
case("train/train-batches-negative", f"{TR} --out run2 trainer.train_batches_per_epoch=-5",
     message="train_batches_per_epoch", klass="traceback")
case("train/val-batches-zero", f"{TR} --out run2 trainer.val_batches=0", outputs=("run2",), message="val_batches",
     klass="silent_wrong", note="0 is read as 'all batches'")
case("train/gradient-clip-negative", f"{TR} --out run2 trainer.gradient_clip_val=-1", outputs=("run2",),
     message="gradient_clip_val", klass="silent_wrong")
case("train/max-time-negative", f"{TR} --out run2 trainer.max_time_minutes=-1", outputs=("run2",),
     message="max_time_minutes", klass="silent_wrong")
case("train/max-epochs-zero", f"{TR} --out run2 trainer.max_epochs=0", message="max_epochs", klass="refusal")
case("train/batch-size-zero", f"{TR} --out run2 data.batch_size=0", message="batch_size", klass="refusal")
case("train/window-zero", f"{TR} --out run2 data.window=0", message="window", klass="traceback")
case("train/window-longer-than-track", f"{TR} --out run2 data.window=500", message="window", klass="traceback")
case("train/eval-stride-zero", f"{TR} --out run2 data.eval_window_stride=0", message="eval_window_stride",
     klass="traceback")
case("train/num-workers-negative", f"{TR} --out run2 data.num_workers=-1", message="num_workers", klass="traceback")
case("train/fold-out-of-range", f"{TR} --out run2 data.fold=5 data.folds=2", message="fold", klass="refusal")
case("train/data-path-user-folder", f"{TR} --out run2 data.path=user", message="user", klass="refusal")
case("train/data-path-a-file", f"{TR} --out run2 data.path=z.csv", message="z.csv", klass="refusal")
case("train/data-path-without-splits", f"{TR} --out run2 data.path=small", setup=unsplit_copy("ds", "small"),
     message="no train/val split", klass="traceback")
case("train/data-path-and-recipe", f"{TR} --out run2 data.recipe=recipe.yaml", message="recipe", klass="refusal")
case("train/data-variant-unknown", f"{TR} --out run2 data.path=null data.variant=loose", message="variant",
     klass="refusal")
case("train/cache-dir-is-a-file", f"{TR} --out run2 data.path=null data.recipe=recipe.yaml data.cache_dir=z.csv",
     message="cache_dir", klass="traceback")
case("train/recipe-name-escapes-cache", f"{TR} --out run2 data.path=null data.recipe=esc.yaml data.cache_dir=cache",
     setup=recipe_set("esc.yaml", name="../../escaped"), outputs=("run2", "cache"), message="name",
     klass="silent_wrong", note="the recipe's name becomes a path: cache/../../escaped-... lands outside the working folder")
case("train/data-tracks-huge", f"{TR} --out run2 data.path=null data.recipe=recipe.yaml data.tracks=999999999999",
     message="tracks", klass="hang")
case("train/data-steps-one", f"{TR} --out run2 data.path=null data.recipe=recipe.yaml data.steps=1", message="steps",
     klass="refusal")
case("train/model-kind-unknown", f"{TR} --out run2 model.kind=transformer", message="kind", klass="refusal")
case("train/model-hidden-empty", f"{TR} --out run2 model.hidden=[]", message="hidden", klass="refusal")
case("train/model-hidden-huge", f"{TR} --out run2 model.hidden=[200000,200000]", message="hidden", klass="hang",
     note="a 40-billion-weight layer")
case("train/model-hidden-too-many-layers", f"{TR} --out run2 model.hidden=[{','.join(['8'] * 65)}]",
     message="model.hidden lists 65 layers; at most 64", klass="hang")
case("train/model-hidden-too-many-weights", f"{TR} --out run2 model.hidden=[16384,16384]",
     message="268,435,456 weights between the hidden layers", klass="hang",
     note="each width is allowed; the 1 GB layer between them is not")
case("train/model-rnn-layers-too-many", f"{TR} --out run2 model.kind=rnn model.rnn_layers=65",
     message="model.rnn_layers in [1, 64]", klass="hang")
case("train/model-filter-longer-than-window", f"{TR} --out run2 model.filter_order=50", outputs=("run2",),
     message="filter_order", klass="silent_wrong", note="two filter layers of order 50 need 98 samples; the window is 20")
case("train/model-dropout-out-of-range", f"{TR} --out run2 model.dropout=1.5", message="dropout", klass="refusal")
case("train/seed-negative", f"{TR} --out run2 seed=-1", outputs=("run2",), message="seed", klass="silent_wrong")
case("train/seed-huge", f"{TR} --out run2 seed=99999999999999999999", message="seed", klass="traceback")
case("train/resume-missing-run", "train --out nope --resume", message="nope", klass="refusal")
case("train/resume-with-other-config", f"{TR} --out run --resume trainer.max_epochs=9", message="config",
     klass="refusal")
# an unreadable last.ckpt is passed over for the newest readable checkpoint (issue 59: was refused)
case("train/resume-truncated-checkpoint", "train --out run --resume", "ok", setup=truncate("run/checkpoints/last.ckpt", 0.5),
     outputs=("run",), message="resuming from run/checkpoints/best.ckpt (run/checkpoints/last.ckpt is not a readable",
     verify=v_run("run"), klass="data_loss")
case("train/resume-empty-checkpoint", "train --out run --resume", "ok",
     setup=write_bytes("run/checkpoints/last.ckpt", b""), outputs=("run",),
     message="resuming from run/checkpoints/best.ckpt (run/checkpoints/last.ckpt is empty", verify=v_run("run"),
     klass="data_loss")
case("train/resume-foreign-checkpoint", "train --out run --resume", "ok",
     setup=torch_edit("run/checkpoints/last.ckpt", "run/checkpoints/last.ckpt", _foreign), outputs=("run",),
     message="resuming from run/checkpoints/best.ckpt (run/checkpoints/last.ckpt is not a pmsr_nn tracker checkpoint",
     verify=v_run("run"), klass="data_loss")
case("train/resume-pickle-payload", "train --out run --resume", "ok", setup=pickle_payload("run/checkpoints/last.ckpt"),
     outputs=("run",), message="last.ckpt holds objects other than tensors", verify=v_run("run"), klass="data_loss",
     note="unpickling would create PWNED (a file outside the outputs)")
case("train/resume-checkpoint-is-directory", "train --out run --resume",
     setup=steps(remove("run/checkpoints/last.ckpt"), mkdir("run/checkpoints/last.ckpt")), message="last.ckpt",
     klass="refusal")
case("train/resume-config-garbage", "train --out run --resume", setup=write("run/config.yaml", "- 1\n"),
     message="config.yaml", klass="refusal")
case("train/resume-config-unknown-key", "train --out run --resume",
     setup=lambda root: (root / "run/config.yaml").write_text((root / "run/config.yaml").read_text() + "extra: 1\n"),
     message="extra", klass="refusal")
case("train/resume-config-missing", "train --out run --resume", setup=remove("run/config.yaml"), message="config.yaml",
     klass="refusal")
case("train/resume-finished-run-ok", "train --out run --resume", "ok", outputs=("run",), verify=v_run("run"),
     klass="refusal")
case("train/sigint-after-checkpoint", "train train_long.yaml --out run_sig", signal=("SIGINT", 1.0),
     signal_after=("run_sig/checkpoints/last.ckpt",), outputs=("run_sig",), timeout=90,
     klass="traceback", note="the checkpoint may stay (for --resume); one line, non-zero exit")
case("train/sigterm-after-checkpoint", "train train_long.yaml --out run_sig", signal=("SIGTERM", 1.0),
     signal_after=("run_sig/checkpoints/last.ckpt",), outputs=("run_sig",), timeout=90,
     klass="traceback")

# the tracker on detections (kind: nebp): refused before anything is written
NEBP_YAML = "kind: nebp\nrecipe: r.yaml\nscenes: {window: 20, targets: [2, 2]}\noptim: {steps: 2, batch_size: 2}\n"
NEBP = steps(write("r.yaml", RECIPE_YAML), write("g.yaml", NEBP_YAML))
case("train/nebp-resume", "train g.yaml --resume --out run3", setup=NEBP, message="can not be resumed",
     klass="refusal")
case("train/nebp-pd-out-of-range", "train g.yaml scenes.pd=[0.5,1.5] --out run3", setup=NEBP,
     message="scenes.pd must lie in (0, 1]", klass="refusal")
case("train/nebp-unknown-key", "train g.yaml optim.stepz=3 --out run3", setup=NEBP, message="unknown key 'stepz'",
     klass="refusal")
case("train/nebp-recipe-missing", "train g.yaml recipe=nope.yaml --out run3", setup=NEBP, message="nope.yaml",
     klass="refusal")
case("train/nebp-out-user", "train g.yaml --out user", setup=NEBP,
     message="holds files that are not a training run", klass="data_loss")
# the hybrid tracker's config (kind: jpda_gain), removed under issue 56: one line naming the removal
GAIN = steps(write("r.yaml", RECIPE_YAML),
             write("g.yaml", NEBP_YAML.replace("kind: nebp", "kind: jpda_gain")))
case("train/jpda-gain-removed", "train g.yaml --out run3", setup=GAIN,
     message="removed from the package under issue 56", klass="refusal")

# ---------------------------------------------------------------------------------------------
# select
# ---------------------------------------------------------------------------------------------
SEL = "select train.yaml --members 1 --fresh-tracks 2"

case("select/out-user", f"{SEL} --out user", message="user", klass="data_loss")
case("select/out-user-file", f"{SEL} --out user/notes.txt", message="notes.txt", klass="traceback")
case("select/out-cwd", f"{SEL} --out .", message="out", klass="data_loss")
case("select/out-inside-file", f"{SEL} --out z.csv/sel", message="z.csv", klass="traceback")
case("select/out-symlink-to-user", f"{SEL} --out link", setup=LINK_USER, message="link", klass="data_loss")
case("select/out-unwritable-sysfs", f"{SEL} --out locked/sel", setup=LOCK, message="locked", klass="traceback")
case("select/ok", "select train.yaml --members 2 --fresh-tracks 2 --out sel", "ok", outputs=("sel",),
     verify=v_files("sel/best.pt", "sel/selection.json"), timeout=150, klass="refusal")
case("select/fresh-tracks-huge", "select train.yaml --members 1 --fresh-tracks 999999999999 --out sel",
     message="fresh", klass="hang")
case("select/members-more-than-tracks", "select train.yaml --members 50 --fresh-tracks 2 --out sel",
     message="members", klass="traceback", note="11 train+val tracks cannot be cut into 50 folds")
case("select/config-sets-fold", f"{SEL} --out sel data.fold=0 data.folds=2", message="fold", klass="refusal")
case("select/accelerator-gpu", f"{SEL} --out sel trainer.accelerator=gpu", message="accelerator", klass="traceback")
case("select/data-path-user-folder", f"{SEL} --out sel data.path=user", message="user", klass="refusal")
case("select/config-missing", "select nope.yaml --out sel", message="nope.yaml", klass="refusal")

# ---------------------------------------------------------------------------------------------
# track
# ---------------------------------------------------------------------------------------------
TZ = f"{TRK} --input z.csv"
N_ROWS = 240  # z.csv: 2 tracks x 120 scans

case("track/out-is-the-input", f"{TZ} --out z.csv", message="z.csv", klass="data_loss")
case("track/out-user-csv", f"{TZ} --out user/data.csv", message="data.csv", klass="data_loss")
case("track/out-dataset-h5", f"{TZ} --out ds/tracks.h5", message="tracks.h5", klass="data_loss")
case("track/out-folder-named-csv", f"{TZ} --out outdir.csv", setup=mkdir("outdir.csv"), message="outdir.csv",
     klass="traceback")
case("track/out-inside-file", f"{TZ} --out z.csv/est.csv", message="z.csv", klass="traceback")
case("track/out-missing-parent", f"{TZ} --out nope/est.csv", message="nope", klass="refusal")
case("track/out-bad-suffix", f"{TZ} --out est.txt", message="est.txt", klass="refusal")
case("track/out-unwritable-sysfs", f"{TZ} --out locked/est.csv", setup=LOCK, message="locked", klass="traceback")
case("track/out-symlink-to-user-file", f"{TZ} --out est.csv", setup=symlink("est.csv", "user/data.csv"),
     message="symbolic link", klass="data_loss",
     note="an output that is a link is refused: writing through it would destroy user/data.csv, replacing it "
          "would surprise whoever made it")
case("track/ok-csv", f"{TZ} --out est.csv", "ok", outputs=("est.csv",), verify=v_csv("est.csv", N_ROWS), klass="refusal")
case("track/ok-h5", f"{TZ} --out est.h5", "ok", outputs=("est.h5",), verify=v_h5("est.h5"), klass="refusal")
case("track/ok-lightning-checkpoint", "track --checkpoint run/checkpoints/last.ckpt --input z.csv --out est.csv", "ok",
     outputs=("est.csv",), verify=v_csv("est.csv", N_ROWS), klass="refusal")
case("track/ok-dataset-input", f"{TRK} --input ds --out est.h5", "ok", outputs=("est.h5",), verify=v_h5("est.h5"),
     klass="refusal")
case("track/ok-dataset-split", f"{TRK} --input ds --split val --out est.csv", "ok", outputs=("est.csv",),
     verify=v_csv("est.csv", 120), klass="refusal")
case("track/ok-stride-one", f"{TZ} --out est.csv --stride 1", "ok", outputs=("est.csv",),
     verify=v_csv("est.csv", N_ROWS), klass="refusal")
case("track/device-unknown", f"{TZ} --out est.csv --device banana", message="device", klass="traceback")
case("track/device-cuda-without-gpu", f"{TZ} --out est.csv --device cuda", message="cuda", klass="traceback")
case("track/device-meta", f"{TZ} --out est.csv --device meta", message="device", klass="traceback")
case("track/stride-longer-than-window", f"{TZ} --out est.csv --stride 100000", message="stride", klass="traceback")
case("track/stride-zero", f"{TZ} --out est.csv --stride 0", message="--stride", klass="refusal")
case("track/csv-utf8-bom-ok", f"{TRK} --input b.csv --out est.csv", "ok",
     setup=csv_edit("b.csv", lambda h, r: (h, r), prefix=b"\xef\xbb\xbf"), outputs=("est.csv",),
     verify=v_csv("est.csv", N_ROWS), klass="silent_wrong", note="Excel writes a BOM")
case("track/csv-crlf-ok", f"{TRK} --input c.csv --out est.csv", "ok", setup=csv_edit("c.csv", lambda h, r: (h, r), newline="\r\n"),
     outputs=("est.csv",), verify=v_csv("est.csv", N_ROWS), klass="silent_wrong")
case("track/csv-columns-reordered-ok", f"{TRK} --input c.csv --out est.csv", "ok",
     setup=csv_edit("c.csv", lambda h, r: (h[::-1], [row[::-1] for row in r])), outputs=("est.csv",),
     verify=v_csv("est.csv", N_ROWS), klass="silent_wrong")
case("track/csv-no-header-ok", f"{TRK} --input c.csv --out est.csv", "ok",
     setup=csv_edit("c.csv", lambda h, r: (None, [row[1:] for row in r if row[0] == "0"])), outputs=("est.csv",),
     verify=v_csv("est.csv", 120), klass="silent_wrong", note="documented: header-less with exactly the expected columns")
case("track/csv-padded-header-ok", f"{TRK} --input c.csv --out est.csv", "ok",
     setup=csv_edit("c.csv", lambda h, r: ([f" {c} " for c in h], r)), outputs=("est.csv",),
     verify=v_csv("est.csv", N_ROWS), klass="silent_wrong")
case("track/csv-tracks-interleaved-ok", f"{TRK} --input c.csv --out est.csv", "ok",
     setup=csv_edit("c.csv", lambda h, r: (h, [x for pair in zip(r[:120], r[120:]) for x in pair])),
     outputs=("est.csv",), verify=v_csv("est.csv", N_ROWS), klass="silent_wrong")
case("track/csv-tracks-of-different-lengths-ok", f"{TRK} --input c.csv --out est.csv", "ok",
     setup=csv_edit("c.csv", lambda h, r: (h, r[:180])), outputs=("est.csv",), verify=v_csv("est.csv", 180),
     klass="silent_wrong")
case("track/csv-nan-hold-ok", f"{TRK} --input c.csv --out est.csv --nan hold", "ok",
     setup=csv_edit("c.csv", set_cell(5, "range_2", "nan")), outputs=("est.csv",), verify=v_csv("est.csv", N_ROWS),
     klass="refusal")
case("track/csv-nan", f"{TRK} --input c.csv --out est.csv", setup=csv_edit("c.csv", set_cell(5, "range_2", "")),
     message="nan", klass="refusal")
case("track/csv-nan-first-row-hold", f"{TRK} --input c.csv --out est.csv --nan hold",
     setup=csv_edit("c.csv", set_cell(0, "azimuth_1", "nan")), message="nan", klass="refusal")
case("track/csv-infinite", f"{TRK} --input c.csv --out est.csv", setup=csv_edit("c.csv", set_cell(7, "range_1", "inf")),
     message="infinite", klass="refusal")
case("track/csv-values-1e300", f"{TRK} --input c.csv --out est.csv", setup=csv_edit("c.csv", map_columns("range", lambda v: 1e300)),
     outputs=("est.csv",), message="range", klass="silent_wrong")
case("track/csv-values-1e300-force-ok", f"{TRK} --input c.csv --out est.csv --force", "ok",
     setup=csv_edit("c.csv", map_columns("range", lambda v: 1e300)), outputs=("est.csv",),
     verify=v_csv("est.csv", N_ROWS, finite=False), message=f"{N_ROWS} of {N_ROWS} estimates are not finite",
     klass="silent_wrong", note="forced past the checks: written, with a warning that counts the non-finite estimates")
case("track/csv-values-1e30", f"{TRK} --input c.csv --out est.csv", setup=csv_edit("c.csv", map_columns("range", lambda v: v * 1e26)),
     outputs=("est.csv",), message="range", klass="silent_wrong")
case("track/csv-azimuth-in-degrees", f"{TRK} --input c.csv --out est.csv",
     setup=csv_edit("c.csv", map_columns("azimuth", math.degrees)), outputs=("est.csv",), message="azimuth",
     klass="silent_wrong")
case("track/csv-negative-ranges", f"{TRK} --input c.csv --out est.csv", setup=csv_edit("c.csv", map_columns("range", lambda v: -v)),
     outputs=("est.csv",), message="range", klass="silent_wrong")
case("track/csv-range-below-baseline", f"{TRK} --input c.csv --out est.csv",
     setup=csv_edit("c.csv", map_columns("range", lambda v: v - 14000.0)), outputs=("est.csv",), message="range",
     klass="silent_wrong", note="bistatic range |p-tx|+|p-rx| cannot be shorter than the 7.5-8.3 km baseline")
case("track/csv-duplicate-column", f"{TRK} --input c.csv --out est.csv",
     setup=csv_edit("c.csv", lambda h, r: (h + ["range_1"], [row + ["0.0"] for row in r])), outputs=("est.csv",),
     message="duplicate", klass="silent_wrong")
case("track/csv-time-column-not-uniform", f"{TRK} --input c.csv --out est.csv",
     setup=csv_edit("c.csv", lambda h, r: (h + ["time_s"], [row + [str(2.0 * (i % 120))] for i, row in enumerate(r)])),
     outputs=("est.csv",), message="time_s", klass="silent_wrong", note="sampled every 2 s; the tracker was trained at 1 s")
case("track/csv-too-short", f"{TRK} --input c.csv --out est.csv", setup=csv_edit("c.csv", lambda h, r: (h, r[:10])),
     message="window", klass="refusal")
case("track/csv-empty", f"{TRK} --input c.csv --out est.csv", setup=write("c.csv", ""), message="c.csv", klass="refusal")
case("track/csv-header-only", f"{TRK} --input c.csv --out est.csv", setup=csv_edit("c.csv", lambda h, r: (h, [])),
     message="c.csv", klass="refusal")
case("track/csv-ragged-row", f"{TRK} --input c.csv --out est.csv",
     setup=csv_edit("c.csv", lambda h, r: (h, r[:3] + [r[3][:-2]] + r[4:])), message="line", klass="refusal")
case("track/csv-text-cell", f"{TRK} --input c.csv --out est.csv", setup=csv_edit("c.csv", set_cell(9, "range_rate_2", "fast")),
     message="fast", klass="refusal")
case("track/csv-missing-column", f"{TRK} --input c.csv --out est.csv",
     setup=csv_edit("c.csv", lambda h, r: (h[:-1], [row[:-1] for row in r])), message="azimuth_3", klass="refusal")
case("track/csv-extra-column", f"{TRK} --input c.csv --out est.csv",
     setup=csv_edit("c.csv", lambda h, r: (h + ["notes"], [row + ["ok"] for row in r])), message="notes", klass="refusal")
case("track/csv-semicolons", f"{TRK} --input c.csv --out est.csv",
     setup=lambda root: (root / "c.csv").write_text((root / "z.csv").read_text().replace(",", ";")), message="c.csv",
     klass="refusal")
case("track/csv-non-utf8", f"{TRK} --input c.csv --out est.csv",
     setup=lambda root: (root / "c.csv").write_bytes((root / "z.csv").read_bytes() + "0,x,é\n".encode("latin-1")),
     message="utf-8", klass="refusal")
case("track/csv-unreadable", f"{TZ} --out est.csv", setup=chmod("z.csv", 0), outputs=("est.csv",), root_expect="ok",
     message="z.csv", klass="refusal")
case("track/input-dataset-h5-file-ok", f"{TRK} --input ds/tracks.h5 --out est.csv", "ok", outputs=("est.csv",),
     verify=v_csv("est.csv", 12 * 120), klass="refusal", note="a dataset's tracks.h5 reads as its folder (issue 21)")
case("track/input-dataset-h5-other-geometry", f"{TRK} --input ds/tracks.h5 --out est.csv",
     setup=edit_json("ds/manifest.json", _move_receiver), message="geometry", klass="silent_wrong",
     note="the folder's manifest is checked as with --input ds")
case("track/input-dataset-h5-out-inside-the-dataset", f"{TRK} --input ds/tracks.h5 --out ds/est.csv",
     message="inside the input", klass="data_loss")
case("track/input-h5-outside-its-dataset", f"{TRK} --input loose/tracks.h5 --out est.csv",
     setup=steps(mkdir("loose"), copy("ds/tracks.h5", "loose/tracks.h5")), message="loose/tracks.h5",
     klass="silent_wrong", note="no manifest beside it: no geometry to check")
case("track/input-foreign-h5", f"{TRK} --input other.h5 --out est.csv", setup=new_foreign_h5("other.h5"),
     message="other.h5", klass="refusal")
case("track/ok-dataset-without-splits", f"{TRK} --input small/tracks.h5 --split test --out est.csv", "ok",
     setup=unsplit_copy("ds", "small"), outputs=("est.csv",), verify=v_csv("est.csv", 12 * 120), klass="refusal")
case("track/split-val-of-dataset-without-splits", f"{TRK} --input small --split val --out est.csv",
     setup=unsplit_copy("ds", "small"), message="no val split", klass="refusal")
case("track/input-dataset-manifest", f"{TRK} --input ds/manifest.json --out est.csv", message="manifest.json",
     klass="silent_wrong")
case("track/input-user-folder", f"{TRK} --input user --out est.csv", message="user", klass="refusal")
case("track/input-missing", f"{TRK} --input nope.csv --out est.csv", message="nope.csv", klass="refusal")
case("track/split-with-csv", f"{TZ} --out est.csv --split val", message="--split", klass="refusal")
case("track/input-other-geometry", f"{TRK} --input ds --out est.csv",
     setup=edit_json("ds/manifest.json", _move_receiver), message="geometry", klass="refusal")
case("track/input-other-dt", f"{TRK} --input ds --out est.csv",
     setup=edit_json("ds/manifest.json", lambda m: m.update(dt_s=2.0)), message="dt", klass="refusal")
case("track/checkpoint-missing", "track --checkpoint nope.pt --input z.csv --out est.csv", message="nope.pt", klass="refusal")
case("track/checkpoint-is-directory", "track --checkpoint user --input z.csv --out est.csv", message="user", klass="refusal")
case("track/checkpoint-is-text", "track --checkpoint z.csv --input z.csv --out est.csv", message="z.csv", klass="refusal")
case("track/checkpoint-empty", "track --checkpoint e.pt --input z.csv --out est.csv", setup=write_bytes("e.pt", b""),
     message="e.pt", klass="refusal")
case("track/checkpoint-truncated", "track --checkpoint t.pt --input z.csv --out est.csv",
     setup=steps(copy("run/tracker.pt", "t.pt"), truncate("t.pt", 0.5)), message="t.pt", klass="refusal")
case("track/checkpoint-with-pickled-object", "track --checkpoint o.pt --input z.csv --out est.csv",
     setup=torch_edit("run/tracker.pt", "o.pt", _with_date), message="o.pt", klass="refusal")
case("track/checkpoint-foreign", "track --checkpoint f.pt --input z.csv --out est.csv",
     setup=torch_edit("run/tracker.pt", "f.pt", _foreign), message="f.pt", klass="refusal")
case("track/checkpoint-nan-weights", "track --checkpoint nan.pt --input z.csv --out est.csv",
     setup=torch_edit("run/tracker.pt", "nan.pt", _nan_weight), outputs=("est.csv",), message="nan", klass="silent_wrong")
case("track/checkpoint-nan-normalisation", "track --checkpoint nan.pt --input z.csv --out est.csv",
     setup=torch_edit("run/tracker.pt", "nan.pt", _nan_normalisation), outputs=("est.csv",), message="normalisation",
     klass="silent_wrong")
case("track/checkpoint-format-version", "track --checkpoint v.pt --input z.csv --out est.csv",
     setup=torch_edit("run/tracker.pt", "v.pt", lambda b: b["pmsr"].update(format_version=2)), message="format",
     klass="refusal")
case("track/checkpoint-without-window", "track --checkpoint w.pt --input z.csv --out est.csv",
     setup=torch_edit("run/tracker.pt", "w.pt", lambda b: b["pmsr"].pop("window") and None), message="window",
     klass="traceback")
case("track/checkpoint-wrong-shapes", "track --checkpoint s.pt --input z.csv --out est.csv",
     setup=torch_edit("run/tracker.pt", "s.pt", _wrong_shape), message="s.pt", klass="refusal")

# ---------------------------------------------------------------------------------------------
# export
# ---------------------------------------------------------------------------------------------
case("export/out-user-file", "export ds --out user/notes.txt", message="notes.txt", klass="data_loss")
case("export/out-dataset-manifest", "export ds --out ds/manifest.json", message="manifest.json", klass="data_loss")
case("export/out-symlink-to-user-file", "export ds --out x.csv", setup=symlink("x.csv", "user/data.csv"),
     outputs=("x.csv",), message="x.csv", klass="data_loss", note="open() follows the link into user/data.csv")
case("export/out-folder", "export ds --out user", message="user", klass="traceback")
case("export/out-inside-file", "export ds --out z.csv/x.csv", message="z.csv", klass="traceback")
case("export/out-missing-parent", "export ds --out nope/x.csv", message="nope", klass="traceback")
case("export/out-unwritable-sysfs", "export ds --out locked/x.csv", setup=LOCK, message="locked", klass="traceback")
case("export/out-disk-full", "export ds --out full.csv", setup=symlink("full.csv", "/dev/full"), outputs=("full.csv",),
     message="full.csv", klass="traceback", note="full.csv -> /dev/full: ENOSPC on write")
case("export/out-readonly-dir", "export ds --out ro/x.csv", setup=RO, outputs=("ro/x.csv",), root_expect="ok",
     message="ro", klass="traceback")
case("export/ok", "export ds --out out.csv", "ok", outputs=("out.csv",), verify=v_csv("out.csv", 12 * 120), klass="refusal")
case("export/ok-split", "export ds --split test --out t.csv", "ok", outputs=("t.csv",), verify=v_csv("t.csv", 120),
     klass="refusal")
case("export/tracks-huge-ok", "export ds --out out.csv --tracks 999999999999", "ok", outputs=("out.csv",),
     verify=v_csv("out.csv", 12 * 120), klass="refusal", note="--tracks is 'at most'")
case("export/split-empty", "export ds --out out.csv --split val", setup=h5_edit("ds/tracks.h5", _all_train),
     message="val", klass="refusal")
case("export/dataset-user-folder", "export user --out out.csv", message="user", klass="refusal")
case("export/dataset-missing", "export nope --out out.csv", message="nope", klass="refusal")
case("export/dataset-is-csv", "export z.csv --out out.csv", message="z.csv", klass="refusal")
case("export/h5-truncated", "export ds --out out.csv", setup=truncate("ds/tracks.h5", 0.6), message="tracks.h5",
     klass="traceback")
case("export/manifest-without-columns", "export ds --out out.csv",
     setup=edit_json("ds/manifest.json", lambda m: m.pop("columns") and None), message="columns", klass="traceback")

# ---------------------------------------------------------------------------------------------
# evaluate
# ---------------------------------------------------------------------------------------------
EV = "evaluate sc.yaml --quiet"

case("evaluate/out-user-overwrite", f"{EV} --out user --overwrite", message="user", klass="data_loss")
case("evaluate/out-cwd-overwrite", f"{EV} --out . --overwrite", message="out", klass="data_loss")
case("evaluate/out-parent-overwrite", f"{EV} --out .. --overwrite", message="out", klass="data_loss")
case("evaluate/out-empty-string-overwrite", ("evaluate", "sc.yaml", "--quiet", "--out", "", "--overwrite"),
     message="out", klass="data_loss", note="Path('') is the working folder")
case("evaluate/out-user-subfolder-overwrite", f"{EV} --out user/sub --overwrite", message="user/sub", klass="data_loss")
case("evaluate/out-user-subfolder", f"{EV} --out user/sub", message="user/sub", klass="refusal")
case("evaluate/out-symlink-to-user-overwrite", f"{EV} --out link --overwrite", setup=LINK_USER, message="link",
     klass="data_loss")
case("evaluate/out-dataset-overwrite", f"{EV} --out ds --overwrite", message="ds", klass="data_loss")
case("evaluate/out-training-run-overwrite", f"{EV} --out run --overwrite", message="run", klass="data_loss")
case("evaluate/out-file-overwrite", f"{EV} --out z.csv --overwrite", message="z.csv", klass="data_loss")
case("evaluate/out-file", f"{EV} --out z.csv", message="z.csv", klass="refusal")
case("evaluate/out-inside-file", f"{EV} --out z.csv/x", message="z.csv", klass="traceback")
case("evaluate/out-unwritable-sysfs", f"{EV} --out locked/ev", setup=LOCK, message="locked", klass="traceback")
case("evaluate/out-readonly-dir", f"{EV} --out ro/ev", setup=RO, outputs=("ro/ev",), root_expect="ok", message="ro",
     klass="traceback")
case("evaluate/ok", f"{EV} --out out", "ok", outputs=("out",), verify=v_results("out"), klass="refusal")
case("evaluate/ok-overwrite-previous-result", f"{EV} --out ev --overwrite", "ok", outputs=("ev",),
     verify=v_results("ev"), klass="data_loss")
case("evaluate/own-result-holding-a-user-file-overwrite", f"{EV} --out ev --overwrite", setup=write("ev/notes.txt", "mine"),
     message="notes.txt", klass="data_loss", note="a file the user added to an earlier result is never deleted")
case("evaluate/ok-existing-empty-folder", f"{EV} --out empty", "ok", setup=mkdir("empty"), outputs=("empty",),
     verify=v_results("empty"), klass="refusal")
case("evaluate/ok-new-parent-folders", f"{EV} --out a/b/c", "ok", outputs=("a",), verify=v_results("a/b/c"),
     klass="refusal")
case("evaluate/ok-learned", "evaluate sc_learned.yaml --quiet --out out", "ok", outputs=("out",),
     verify=v_results("out"), klass="refusal")
case("evaluate/ok-lightning-checkpoint", "evaluate sc_learned.yaml --quiet --out out --checkpoint MDFNN=run/checkpoints/last.ckpt",
     "ok", outputs=("out",), verify=v_results("out"), klass="refusal")
case("evaluate/methods-ok", f"{EV} --out out --methods UKF", "ok", outputs=("out",),
     verify=v_results("out", rows=("UKF",)), klass="refusal")
case("evaluate/methods-unknown-row", f"{EV} --out out --methods EKF,PF",
     message="--methods 'PF': not a row of scenario 'tiny', whose rows are: EKF, UKF", klass="refusal")
case("evaluate/methods-empty", f"{EV} --out out --methods ,", message="whose rows are: EKF, UKF", klass="refusal")
case("evaluate/methods-with-executor", f"{EV} --out out --methods EKF --executor local",
     message="--methods does not reach the jobs of --executor", klass="refusal")
case("evaluate/out-in-proc", f"{EV} --out proc/ev", setup=symlink("proc", "/proc"),
     message="virtual file system with no disk behind it", klass="traceback")
case("evaluate/shard-garbage", f"{EV} --out out --shard abc", message="shard", klass="refusal")
case("evaluate/shard-zero", f"{EV} --out out --shard 0/2", message="shard", klass="refusal")
case("evaluate/shard-more-than-blocks", f"{EV} --out out --shard 1/3", message="shard", klass="refusal")
case("evaluate/shard-negative", f"{EV} --out out --shard -1/2", message="shard", klass="refusal")
case("evaluate/mc-runs-huge", f"{EV} --out out --mc-runs 999999999999", message="mc-runs", klass="hang")
case("evaluate/checkpoint-for-classical-method", f"{EV} --out out --checkpoint EKF=run/tracker.pt", message="EKF",
     klass="refusal")
case("evaluate/checkpoint-unknown-method", f"{EV} --out out --checkpoint NOPE=run/tracker.pt", message="NOPE",
     klass="refusal")
case("evaluate/checkpoint-without-name", f"{EV} --out out --checkpoint run/tracker.pt", message="--checkpoint",
     klass="refusal")
case("evaluate/checkpoint-missing-file", "evaluate sc_learned.yaml --quiet --out out --checkpoint MDFNN=nope.pt",
     message="nope.pt", klass="refusal")
case("evaluate/checkpoint-nan-weights", "evaluate sc_learned.yaml --quiet --out out --checkpoint MDFNN=nan.pt",
     setup=torch_edit("run/tracker.pt", "nan.pt", _nan_weight), outputs=("out",), message="nan", klass="silent_wrong")
case("evaluate/learned-stride-zero", "evaluate s.yaml --quiet --out out", setup=scenario_learned_options("s.yaml", {"stride": 0}),
     outputs=("out",), message="stride", klass="silent_wrong", note="0 is read as 'default stride'")
case("evaluate/learned-stride-huge", "evaluate s.yaml --quiet --out out",
     setup=scenario_learned_options("s.yaml", {"stride": 100000}), message="stride", klass="traceback")
case("evaluate/learned-whole-sequence-finite-context", "evaluate s.yaml --quiet --out out",
     setup=scenario_learned_options("s.yaml", {"inference": "whole_sequence"}), message="whole_sequence",
     klass="refusal", note="an MDFNN reads a finite window: a whole-sequence pass is not defined for it")
case("evaluate/learned-inference-unknown", "evaluate s.yaml --quiet --out out",
     setup=scenario_learned_options("s.yaml", {"inference": "sideways"}), message="inference", klass="refusal")
case("evaluate/device-unknown", f"{EV} --out out --device banana", outputs=("out",), message="device", klass="silent_wrong")
case("evaluate/device-cuda-without-gpu", f"{EV} --out out --device cuda", message="cuda", klass="traceback")
case("evaluate/scenario-alias-bomb", "evaluate s.yaml --out out",
     setup=text_sub(SCENARIO_YAML, "s.yaml", "seed: 3", f"seed: {BOMB}"), message="alias", klass="hang")
case("evaluate/scenario-million-element-list", "evaluate s.yaml --out out",
     setup=text_sub(SCENARIO_YAML, "s.yaml", "seed: 3", "seed: [" + ",".join(["3"] * 1_000_000) + "]"),
     message="seed (line 3) is a list of 1,000,000 values", klass="hang",
     note="no alias in it: refused as it is read (0.6 s here), not called an alias bomb after 30 s")
case("evaluate/scenario-deep-nesting", "evaluate s.yaml --out out",
     setup=text_sub(SCENARIO_YAML, "s.yaml", "seed: 3", f"seed: {DEEP}"), message="s.yaml", klass="traceback")
case("evaluate/scenario-50mb", "evaluate s.yaml --out out", setup=big_yaml("s.yaml", SCENARIO_YAML, 50, key="description"),
     message="s.yaml", klass="hang")
case("evaluate/scenario-non-utf8", "evaluate s.yaml --out out",
     setup=write_bytes("s.yaml", SCENARIO_YAML.encode() + "description: trajectoire d'été\n".encode("latin-1")),
     message="utf-8", klass="traceback")
case("evaluate/scenario-duplicate-key", "evaluate s.yaml --quiet --out out",
     setup=write("s.yaml", SCENARIO_YAML + "seed: 4\n"), outputs=("out",), message="duplicate", klass="silent_wrong")
case("evaluate/scenario-top-level-list", "evaluate l.yaml --out out", setup=write("l.yaml", "- 1\n"), message="mapping",
     klass="refusal")
case("evaluate/scenario-missing", "evaluate nope.yaml --out out", message="nope.yaml", klass="refusal")
case("evaluate/scenario-is-directory", "evaluate user --out out", message="user", klass="refusal")
case("evaluate/scenario-is-csv", "evaluate z.csv --out out", message="z.csv", klass="refusal")
case("evaluate/yaml-3e1-noise-ok", "evaluate s.yaml --quiet --out out", "ok",
     setup=text_sub(SCENARIO_YAML, "s.yaml", "range_m: 30.0", "range_m: 3e1"), outputs=("out",),
     verify=v_results("out"), klass="silent_wrong")
case("evaluate/yaml-dot5-ramp-ok", "evaluate s.yaml --quiet --out out", "ok",
     setup=write("s.yaml", SCENARIO_YAML + "ramp_s: .5\n"), outputs=("out",), verify=v_results("out"), klass="silent_wrong")
case("evaluate/method-kind-unknown", "evaluate s.yaml --out out",
     setup=scenario_method("s.yaml", {"name": "X", "kind": "magic"}), message="kind", klass="refusal")
case("evaluate/method-option-unknown", "evaluate s.yaml --out out",
     setup=scenario_method("s.yaml", {"name": "X", "kind": "ekf", "options": {"gain": 2}}), message="gain", klass="refusal")
case("evaluate/pf-particles-zero", "evaluate s.yaml --quiet --out out",
     setup=scenario_method("s.yaml", {"name": "PF", "kind": "particle_filter", "options": {"particles": 0}}),
     message="particles", klass="traceback")
case("evaluate/pf-particles-text", "evaluate s.yaml --quiet --out out",
     setup=scenario_method("s.yaml", {"name": "PF", "kind": "particle_filter", "options": {"particles": "many"}}),
     message="particles", klass="traceback")
case("evaluate/pf-particles-huge", "evaluate s.yaml --quiet --out out",
     setup=scenario_method("s.yaml", {"name": "PF", "kind": "particle_filter", "options": {"particles": 200000000}}),
     message="particles", klass="hang")
case("evaluate/pf-roughening-negative", "evaluate s.yaml --quiet --out out",
     setup=scenario_method("s.yaml", {"name": "PF", "kind": "particle_filter", "options": {"particles": 100, "roughening": -1.0}}),
     outputs=("out",), message="roughening", klass="silent_wrong")
case("evaluate/sikf-refine-negative", "evaluate s.yaml --quiet --out out",
     setup=scenario_method("s.yaml", {"name": "SI", "kind": "si_kf", "options": {"refine_steps": -2}}),
     outputs=("out",), message="refine_steps", klass="silent_wrong")
case("evaluate/case-outside-envelope", "evaluate s.yaml --out out",
     setup=yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: d["cases"][0].update(start_range_m=10900.0, heading_deg=90.0,
                                                                             start_bearing_deg=90.0)),
     message="envelope", klass="refusal")
case("evaluate/case-no-segments", "evaluate s.yaml --out out",
     setup=yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: d["cases"][0].update(segments=[])), message="segments",
     klass="refusal")
case("evaluate/case-duration-huge", "evaluate s.yaml --quiet --out out",
     setup=yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: d["cases"][0].update(segments=[{"duration_s": 100000000.0}])),
     message="duration", klass="hang")
case("evaluate/case-duration-below-one-step", "evaluate s.yaml --quiet --out out",
     setup=yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: d["cases"][0].update(segments=[{"duration_s": 0.5}])),
     message="0.5", klass="traceback")
case("evaluate/warmup-longer-than-case", "evaluate s.yaml --out out", setup=scenario_set(warmup_steps=10000),
     message="warmup", klass="refusal")
case("evaluate/block-runs-zero", "evaluate s.yaml --out out", setup=scenario_set(block_runs=0), message="block_runs",
     klass="refusal")
case("evaluate/duplicate-case-names", "evaluate s.yaml --out out",
     setup=yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: d["cases"].append(dict(d["cases"][0]))), message="duplicate",
     klass="refusal")
case("evaluate/recipe-missing", "evaluate s.yaml --out out", setup=scenario_set(recipe="nope.yaml"), message="nope.yaml",
     klass="refusal")
case("evaluate/recipe-3d", "evaluate s.yaml --out out",
     setup=steps(recipe_set("r3.yaml", dim=3), scenario_set(recipe="r3.yaml")), message="planar", klass="refusal")
case("evaluate/recipe-duplicate-receivers", "evaluate s.yaml --quiet --out out",
     setup=steps(recipe_set("rd.yaml", geometry__receivers=[{"baseline_m": 7560.0, "bearing_deg": 240.0},
                                                            {"baseline_m": 7560.0, "bearing_deg": 240.0}]),
                 scenario_set(recipe="rd.yaml")),
     outputs=("out",), message="receiver", klass="silent_wrong")
case("evaluate/reference-file-missing", "evaluate s.yaml --out out",
     setup=scenario_set(reference={"file": "nope.json", "table": "a.b"}), message="nope.json", klass="refusal")
case("evaluate/reference-table-missing", "evaluate s.yaml --out out",
     setup=steps(write("ref.json", '{"a": {"c": 1}}'), scenario_set(reference={"file": "ref.json", "table": "a.b"})),
     message="a.b", klass="refusal")
case("evaluate/seed-negative", "evaluate s.yaml --quiet --out out", setup=scenario_set(seed=-1), outputs=("out",),
     message="seed", klass="silent_wrong")
case("evaluate/noise-zero", "evaluate s.yaml --out out", setup=scenario_set(noise={"range_m": 0.0}), message="noise",
     klass="refusal")
case("evaluate/multitarget-incomplete", "evaluate mt.yaml --out out --shard 1/2",
     setup=write("mt.yaml", "kind: multitarget\nname: mt\n"), message="'kind: multitarget' scenarios are retired",
     klass="refusal")
case("evaluate/product-not-made", "evaluate s.yaml --out out",
     setup=scenario_method("s.yaml", {"name": "JPDA", "kind": "s_msjpda"}), message="reads detections",
     klass="refusal")
_TWO = [{"name": "a", "start_range_m": 4000.0, "start_bearing_deg": 130.0, "speed_mps": 10.0, "heading_deg": 20.0,
         "segments": [{"duration_s": 300.0}]}]
case("evaluate/target-death-before-birth", "evaluate s.yaml --out out",
     setup=yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: d["cases"].__setitem__(0, {"name": "c", "targets": [
         {**_TWO[0], "birth_s": 100.0, "death_s": 50.0}]})), message="death before birth", klass="refusal")
case("evaluate/target-out-of-envelope", "evaluate s.yaml --out out",
     setup=yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: d["cases"].__setitem__(0, {"name": "c", "targets": [
         {**_TWO[0], "start_range_m": 60000.0}]})), message="envelope", klass="refusal")
case("evaluate/two-products-one-stream", "evaluate s.yaml --out out",
     setup=yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: (d.update(detections={"pd": 0.9}),
                                                          d["methods"].append({"name": "J", "kind": "s_msjpda"}))),
     message="random_streams", klass="refusal")
# a single-frequency network (two transmitters, one frequency): a receiver's detections pooled
SFN_RECIPE_YAML = RECIPE_YAML + """\
geometry:
  transmitters: [{position_m: [0.0, 0.0], carrier_hz: 98.0e+6}, {position_m: [0.0, 12000.0], carrier_hz: 98.0e+6}]
  receivers: [{baseline_m: 7560.0, bearing_deg: 240.0}, {baseline_m: 8120.0, bearing_deg: 270.0}]
"""
case("evaluate/pooled-clutter-odd-count", "evaluate s.yaml --out out",
     setup=steps(write("sfn.yaml", SFN_RECIPE_YAML), yaml_edit(SCENARIO_YAML, "s.yaml", lambda d: (
         d.update(recipe="sfn.yaml", random_streams="per_product",
                  detections={"pd": 0.9, "illuminator_known": False, "clutter": {"per_scan": 3, "model": "fixed"}}),
         d["methods"].append({"name": "P3", "kind": "pmht_3d", "options": {"initiation": "detections"}})))),
     message="3 fixed clutter points per receiver list do not split evenly over its 2 pairs", klass="refusal",
     note="a fixed count per receiver list must split over the receiver's pairs (illuminator_known: false)")
PMHT_YAML = """\
name: pmht_tiny
mc_runs: 2
block_runs: 2
world:
  scans: 12
  dimensions: 3
  geometry:
    transmitters: [{position_m: [29434.0, -34761.0, 293.0], carrier_hz: 500.0e+6},
                   {position_m: [12845.0, -106922.0, 293.0], carrier_hz: 500.0e+6}]
    receivers: [{position_m: [0.0, 0.0, 0.0]}]
  motion: {dt_s: 1.0, q: 5.0, model: cv_continuous, truth: straight}
noise: {range_m: 50.0, doppler_hz: 20.0}
detections:
  pd: 0.8
  components: [range, doppler]
  clutter: {per_scan: 4, model: fixed, range_m: [40000.0, 260000.0], doppler_hz: [-1000.0, 1000.0]}
  illuminator_known: false
loss: {}
warmup_steps: 2
divergence_m: null
cases: [{name: c, states: [{position_m: [-55000.0, -3498.0, 890.0], velocity_mps: [200.0, 10.0, 0.0]}]}]
methods: [{name: P, kind: pmht_3d, options: {window: 5, overlap: 2}}]
"""
case("evaluate/pmht-window-longer-than-scans", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(window=20)),
     message="window of 20 scans is longer", klass="refusal")
case("evaluate/pmht-zero-em-iterations", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(em_iterations=0)),
     message="em_iterations", klass="refusal")
case("evaluate/pmht-overlap-whole-window", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(overlap=5)),
     message="overlap", klass="refusal")
case("evaluate/pmht-clutter-does-not-split-over-illuminators", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["detections"]["clutter"].update(per_scan=5)),
     message="split evenly",
     klass="refusal")
case("evaluate/pmht-2d-target-in-3d-scenario", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["cases"][0]["states"][0].update(position_m=[0.0, 1.0],
                                                                                      velocity_mps=[1.0, 0.0])),
     message="states[0]", klass="refusal")
case("evaluate/pmht-anneal-below-one", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(anneal=0.5)),
     message="anneal", klass="refusal")
case("evaluate/stonesoup-unknown-tracker", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["methods"].append({"name": "S", "kind": "stonesoup",
                                                                        "options": {"tracker": "mht"}})),
     message="must be one of jpda, gnn", klass="refusal")
case("evaluate/p-msjpda-unknown-m-best-search", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["methods"].append({"name": "PJ", "kind": "p_msjpda",
                                                                        "options": {"m_best_search": "murty"}})),
     message="option m_best_search must be one of branch_and_bound, relaxation", klass="refusal")
case("evaluate/s-msjpda-bias-test-on-handed-tracks", "evaluate p.yaml --out out",
     setup=yaml_edit(PMHT_YAML, "p.yaml", lambda d: d["methods"].append({"name": "SJ", "kind": "s_msjpda",
                                                                        "options": {"bias_window": 20}})),
     message="the innovation bias test (bias_window) acts on the tracks a sequential tracker starts itself",
     klass="refusal")
FM_YAML = """\
name: fm_tiny
mc_runs: 1
block_runs: 1
world:
  scans: 3
  geometry:
    transmitters: [{position_m: [6500.0, 0.0], carrier_hz: 100.0e+6}]
    receivers: [{position_m: [0.0, 0.0]}]
noise: {range_m: 1500.0, doppler_hz: 1.5}
detections:
  pd: 0.8
  components: [range, doppler]
  clutter: {per_scan: 1, model: poisson, range_m: [0.0, 60000.0], doppler_hz: [-120.0, 120.0]}
  front_end:
    signal: {sample_rate_hz: 64000.0, cpi_s: 0.25, audio_bandwidth_hz: 4000.0, deviation_hz: 5000.0}
    max_range_m: 40000.0
    max_doppler_hz: 120.0
    batch_len: 250
    cancellation: {range_bins: 4}
    cfar: {guard: [1, 1], train: [4, 2], pfa: 1.0e-3}
loss: {}
warmup_steps: 1
divergence_m: null
cases: [{name: c, states: [{position_m: [10000.0, 10000.0], velocity_mps: [60.0, 80.0]}]}]
methods: [{name: J, kind: s_msjpda}]
"""
case("evaluate/front-end-cpi-shorter-than-longest-delay", "evaluate fm.yaml --out out",
     setup=yaml_edit(FM_YAML, "fm.yaml", lambda d: (d["detections"]["front_end"]["signal"].update(cpi_s=0.0005),
                                                 d["detections"]["front_end"].update(max_range_m=200000.0))),
     message="shorter than the longest delay", klass="refusal")
case("evaluate/front-end-sample-rate-cannot-resolve-range", "evaluate fm.yaml --out out",
     setup=yaml_edit(FM_YAML, "fm.yaml", lambda d: d["detections"]["front_end"].update(max_range_m=3000.0)),
     message="can not resolve the requested max_range_m", klass="refusal")
case("evaluate/front-end-cfar-window-larger-than-map", "evaluate fm.yaml --out out",
     setup=yaml_edit(FM_YAML, "fm.yaml", lambda d: d["detections"]["front_end"]["cfar"].update(guard=[2, 4], train=[4, 4])),
     message="larger than the", klass="refusal")
case("evaluate/front-end-cfar-alpha-factor-not-positive", "evaluate fm.yaml --out out",
     setup=yaml_edit(FM_YAML, "fm.yaml", lambda d: d["detections"]["front_end"]["cfar"].update(alpha_factor=0.0)),
     message="cfar alpha_factor must be positive and finite, got 0.0", klass="refusal")
case("evaluate/front-end-doppler-beyond-ambiguity", "evaluate fm.yaml --out out",
     setup=yaml_edit(FM_YAML, "fm.yaml", lambda d: d["detections"]["front_end"].update(max_doppler_hz=128.0)),
     message="max_doppler_hz", klass="refusal")


def _recording(nan_at: int | None = None, rate: float = 64000.0) -> Callable[[Path], None]:
    """An I/Q recording of two 0.25 s CPIs at 64 kHz (noise and a direct path), NaN at one sample."""
    def f(root: Path) -> None:
        import h5py
        import numpy as np

        rng = np.random.default_rng(0)
        n = 2 * 16000
        ref = np.exp(1j * np.cumsum(rng.normal(0, 0.3, n))) * 100 + rng.normal(0, 1, n) + 1j * rng.normal(0, 1, n)
        surv = ref * 10 + rng.normal(0, 1, n) + 1j * rng.normal(0, 1, n)
        if nan_at is not None:
            surv[nan_at] = np.nan
        with h5py.File(root / "iq.h5", "w") as fh:
            fh.create_dataset("ref", data=ref)
            fh.create_dataset("surv", data=surv)
            fh.attrs["sample_rate_hz"] = rate
        yaml_edit(FM_YAML, "fm.yaml", lambda d: None)(root)
    return f


case("front-end/ok", "front-end iq.h5 --settings fm.yaml --out fe", expect="ok", setup=_recording(), outputs=("fe",))
case("front-end/non-finite-samples", "front-end iq.h5 --settings fm.yaml --out fe", setup=_recording(nan_at=20000),
     message="non-finite samples", klass="refusal")
case("front-end/sample-rate-mismatch", "front-end iq.h5 --settings fm.yaml --out fe", setup=_recording(rate=48000.0),
     message="sampled at 48000 Hz", klass="refusal")
case("front-end/not-hdf5", "front-end fm.yaml --settings fm.yaml --out fe",
     setup=yaml_edit(FM_YAML, "fm.yaml", lambda d: None), message="not a readable HDF5", klass="refusal")
case("front-end/out-is-the-recording", "front-end iq.h5 --settings fm.yaml --out iq.h5 --overwrite", setup=_recording(),
     klass="data_loss")
_SIG_EV = ("evaluate sc_big.yaml --quiet --out big", ("big.partial*", ".big.partial*", "big"))
case("evaluate/sigterm", _SIG_EV[0], signal=("SIGTERM", 2.0), signal_after=_SIG_EV[1], klass="traceback",
     note="a killed evaluate must not leave big.partial-XXXX behind")
case("evaluate/sighup", _SIG_EV[0], signal=("SIGHUP", 2.0), signal_after=_SIG_EV[1], klass="traceback")
case("evaluate/sigint", _SIG_EV[0], signal=("SIGINT", 2.0), signal_after=_SIG_EV[1], klass="traceback")
case("evaluate/sigterm-while-overwriting", "evaluate sc_big.yaml --quiet --out ev --overwrite", signal=("SIGTERM", 2.0),
     signal_after=("ev.partial*", ".ev.partial*"), klass="data_loss",
     note="the previous result must survive an interrupted overwrite")

# ---------------------------------------------------------------------------------------------
# merge
# ---------------------------------------------------------------------------------------------
MG = "merge shard1 shard2"

case("merge/out-is-an-input-overwrite", f"{MG} --out shard1 --overwrite", message="shard1", klass="data_loss")
case("merge/out-is-an-input", f"{MG} --out shard1", message="shard1", klass="refusal")
case("merge/out-user-overwrite", f"{MG} --out user --overwrite", message="user", klass="data_loss")
case("merge/out-cwd-overwrite", f"{MG} --out . --overwrite", message="out", klass="data_loss")
case("merge/out-file-overwrite", f"{MG} --out z.csv --overwrite", message="z.csv", klass="data_loss")
case("merge/out-symlink-to-user-overwrite", f"{MG} --out link --overwrite", setup=LINK_USER, message="link",
     klass="data_loss")
case("merge/out-inside-file", f"{MG} --out z.csv/m", message="z.csv", klass="traceback")
case("merge/out-unwritable-sysfs", f"{MG} --out locked/m", setup=LOCK, message="locked", klass="traceback")
case("merge/ok", f"{MG} --out m", "ok", outputs=("m",), verify=v_results("m"), klass="refusal")
case("merge/ok-shards-reversed", "merge shard2 shard1 --out m", "ok", outputs=("m",), verify=v_results("m"),
     klass="refusal")
case("merge/ok-overwrite-previous-result", f"{MG} --out ev --overwrite", "ok", outputs=("ev",), verify=v_results("ev"),
     klass="data_loss")
case("merge/same-shard-twice", "merge shard1 shard1 --out m", message="shard1", klass="refusal")
case("merge/same-shard-via-symlink", "merge shard1 alias shard2 --out m", setup=symlink("alias", "shard1"),
     message="alias", klass="refusal")
case("merge/missing-shard", "merge shard1 --out m", message="blocks", klass="refusal")
case("merge/shard-given-three-times", "merge shard1 shard2 shard2 --out m", message="shard2", klass="refusal")

# compare (reads two results; writes nothing)
case("compare/ok-same-results", "compare ev ev/results.json", "ok", klass="refusal")
case("compare/missing", "compare ev nothing-here", message="no results.json", klass="refusal")
case("compare/a-shard-is-not-results", "compare ev shard1", message="shard1", klass="refusal")
case("compare/not-json", "compare ev z.csv", message="z.csv", klass="refusal")
case("compare/threshold-zero", "compare ev ev --threshold 0", message="--threshold", klass="refusal")

# issue 59 round three: compare, banks, executor
def results_edit(dst: str, fn: Callable[[dict], None]) -> Callable[[Path], None]:
    """``dst``: a copy of the fixture's ev/results.json, changed in place by ``fn``."""
    return steps(copy("ev/results.json", dst), edit_json(dst, lambda r: (fn(r), None)[1]))


def _row(res: dict) -> dict:
    return res["cases"]["steady"]["methods"]["EKF"]


def v_bank_rebuilt(root: Path) -> str | None:
    """The bank's bank.json back, byte for byte the one its first command wrote, and both blocks there."""
    got, was = root / "bank" / "bank.json", root / "bank.json.was"
    if not got.is_file() or got.read_bytes() != was.read_bytes():
        return "bank/bank.json not rebuilt as the bank's first command wrote it"
    return None if (root / "bank" / "block-0001" / "blocks.npz").is_file() else "bank/block-0001 not run again"


LOSE_BANK_FILE = steps(copy("bank/bank.json", "bank.json.was"), remove("bank/bank.json"))
case("compare/figure-a-string", "compare ev new.json", setup=results_edit("new.json", lambda r: _row(r).update(
    rmse_pos_m="10.5")), message="new.json: cases.steady.methods.EKF.rmse_pos_m: expected a number", klass="silent_wrong",
     note="was exit 0, the figure reported as 'only old'")
case("compare/figure-a-boolean", "compare new.json ev", setup=results_edit("new.json", lambda r: _row(r).update(
    rmse_pos_m=True)), message="new.json: cases.steady.methods.EKF.rmse_pos_m: expected a number", klass="silent_wrong")
case("compare/cases-a-list", "compare ev new.json", setup=results_edit("new.json", lambda r: r.update(
    cases=list(r["cases"]))), message="new.json: cases: expected a table", klass="traceback")
case("compare/methods-a-list", "compare ev new.json", setup=results_edit("new.json", lambda r: r["cases"]["steady"].update(
    methods=["EKF", "UKF"])), message="new.json: cases.steady.methods: expected a table", klass="traceback")
case("compare/negative-standard-error", "compare ev new.json", setup=results_edit("new.json", lambda r: _row(r).update(
    rmse_pos_se_m=-1.0)), message="new.json: cases.steady.methods.EKF.rmse_pos_se_m: expected a non-negative number",
     klass="silent_wrong", note="was accepted, verdict 'within error'")
case("compare/missing-figure", "compare ev new.json", setup=results_edit("new.json", lambda r: _row(r).pop(
    "rmse_pos_m")), message="new.json: cases.steady.methods.EKF: lacks the key 'rmse_pos_m'", klass="silent_wrong")
case("compare/missing-methods", "compare ev new.json", setup=results_edit("new.json", lambda r: r["cases"]["steady"].pop(
    "methods")), message="new.json: cases.steady: lacks the key 'methods'", klass="silent_wrong")
case("evaluate/bank-without-bank-json-resumes", "evaluate sc.yaml --quiet --per-block --out bank", "ok",
     setup=steps(LOSE_BANK_FILE, remove("bank/block-0001")), outputs=("bank",), verify=v_bank_rebuilt,
     klass="refusal", note="was 'holds the output of pmsr evaluate, not blocks of ...'; every block names the scenario")
case("evaluate/bank-without-bank-json-other-seed", "evaluate sc.yaml --quiet --per-block --out bank --seed 4",
     setup=LOSE_BANK_FILE, message="bank has 2 block(s) of 'pmsr evaluate --per-block' but no bank.json",
     klass="refusal")
case("evaluate/bank-json-garbage", "evaluate sc.yaml --quiet --per-block --out bank",
     setup=write("bank/bank.json", "{{{"), message="bank.json that is not a bank's", klass="refusal")
case("merge/bank-without-bank-json", "merge bank --out m", "ok", setup=LOSE_BANK_FILE, outputs=("m",),
     verify=v_results("m"), klass="refusal", note="was 'not a shard folder'; the blocks name their scenario")
case("evaluate/executor-slurm-off-cluster", f"{EV} --out jobs --executor slurm", message="no SLURM cluster found",
     klass="traceback", note="was 'unexpected RuntimeError: Could not detect srun ... a bug'; "
     "assumes srun/sbatch are not on PATH (the tests run off a cluster)")
case("merge/not-a-shard", "merge shard1 user --out m", message="user", klass="refusal")
case("merge/shard-folder-missing", "merge shard1 nope --out m", message="nope", klass="refusal")
case("merge/full-result-not-a-shard", "merge ev --out m", message="ev", klass="refusal")
case("merge/npz-truncated", f"{MG} --out m", setup=truncate("shard2/blocks.npz", 0.5), message="blocks.npz",
     klass="traceback")
case("merge/npz-empty", f"{MG} --out m", setup=write_bytes("shard2/blocks.npz", b""), message="blocks.npz",
     klass="traceback")
case("merge/npz-missing", f"{MG} --out m", setup=remove("shard2/blocks.npz"), message="blocks.npz", klass="refusal")
case("merge/npz-pickled-object", f"{MG} --out m", setup=npz_edit("shard2/blocks.npz", _object_blocks),
     message="blocks.npz", klass="refusal")
case("merge/npz-without-blocks", f"{MG} --out m", setup=npz_edit("shard2/blocks.npz", _no_blocks),
     message="blocks.npz", klass="refusal")
case("merge/json-garbage", f"{MG} --out m", setup=write("shard2/shard.json", "{{{"), message="shard.json", klass="refusal")
case("merge/json-list", f"{MG} --out m", setup=write("shard2/shard.json", "[1, 2]"), message="shard.json",
     klass="traceback")
case("merge/json-without-scenario", f"{MG} --out m", setup=edit_json("shard2/shard.json", lambda m: m.pop("scenario") and None),
     message="shard.json", klass="traceback")
case("merge/json-non-utf8", f"{MG} --out m", setup=write_bytes("shard2/shard.json", b'{"format": "\xe9"}'),
     message="shard.json", klass="refusal")
case("merge/json-wrong-format", f"{MG} --out m", setup=edit_json("shard2/shard.json", lambda m: m.update(format="x/9")),
     message="shard.json", klass="refusal")
case("merge/json-other-scenario", f"{MG} --out m",
     setup=edit_json("shard2/shard.json", lambda m: m["scenario"].update(seed=99)), message="scenario", klass="refusal")
case("merge/no-shards", "merge --out m", message="shards", klass="refusal")

# ---------------------------------------------------------------------------------------------
# issue 59 round three: train
# ---------------------------------------------------------------------------------------------
def move(src: str, dst: str) -> Callable[[Path], None]:
    def f(root: Path) -> None:
        (root / dst).parent.mkdir(parents=True, exist_ok=True)
        os.replace(root / src, root / dst)
    return f


def v_resumed(rel: str, ckpt: str | None) -> Callable[[Path], str | None]:
    """A finished run (:func:`v_run`) whose metrics.json says it was resumed from ``ckpt`` (None: started afresh)."""
    def v(root: Path) -> str | None:
        bad = v_run(rel)(root)
        if bad:
            return bad
        said = json.loads((root / rel / "metrics.json").read_text())["resumed_from"]
        return None if said == ckpt else f"resumed_from {said!r}, expected {ckpt!r}"
    return v


NO_CKPT = steps(remove("run/checkpoints/last.ckpt"), remove("run/checkpoints/best.ckpt"))
NEVER_CHECKPOINTED = steps(mkdir("fresh"), copy("run/config.yaml", "fresh/config.yaml"),
                           copy("run/.pmsr_output.json", "fresh/.pmsr_output.json"))
TWO_RX = [{"baseline_m": 7560.0, "bearing_deg": 240.0}, {"baseline_m": 8120.0, "bearing_deg": 270.0}]
case("train/resume-last-deleted-ok", "train --out run --resume", "ok", setup=remove("run/checkpoints/last.ckpt"),
     outputs=("run",), message="resuming from run/checkpoints/best.ckpt (no checkpoint at run/checkpoints/last.ckpt)",
     verify=v_resumed("run", "run/checkpoints/best.ckpt"), klass="data_loss",
     note="was: exit 0, trained afresh from epoch 0 and replaced best.ckpt, tracker.pt and metrics.json")
case("train/resume-last-moved-away-ok", "train --out run --resume", "ok",
     setup=move("run/checkpoints/last.ckpt", "tidy/last.ckpt"), outputs=("run",),
     message="resuming from run/checkpoints/best.ckpt (no checkpoint at run/checkpoints/last.ckpt)",
     verify=v_resumed("run", "run/checkpoints/best.ckpt"), klass="data_loss")
case("train/resume-last-renamed-ok", "train --out run --resume", "ok",
     setup=steps(move("run/checkpoints/last.ckpt", "run/checkpoints/kept.ckpt"),
                 lambda root: os.utime(root / "run/checkpoints/kept.ckpt")), outputs=("run",),
     message="resuming from run/checkpoints/kept.ckpt (no checkpoint at run/checkpoints/last.ckpt)",
     verify=v_resumed("run", "run/checkpoints/kept.ckpt"), klass="data_loss",
     note="the newest readable checkpoint of the run's checkpoints/ folder")
case("train/resume-no-checkpoint", "train --out run --resume", setup=NO_CKPT,
     message="cannot resume run: no readable checkpoint in run/checkpoints", klass="data_loss",
     note="starting afresh would replace tracker.pt and metrics.json")
case("train/resume-no-readable-checkpoint", "train --out run --resume",
     setup=steps(truncate("run/checkpoints/last.ckpt", 0.5), write_bytes("run/checkpoints/best.ckpt", b"")),
     message="replace its last.ckpt, best.ckpt, tracker.pt, metrics.json", klass="data_loss")
case("train/resume-never-checkpointed-ok", "train --out fresh --resume", "ok", setup=NEVER_CHECKPOINTED,
     outputs=("fresh",), message="it has no checkpoint yet", verify=v_resumed("fresh", None), klass="refusal",
     note="a run killed outright before its first checkpoint: nothing to lose, it starts afresh")
case("evaluate/learned-row-other-pair-count", "evaluate s.yaml --quiet --out out",
     setup=steps(recipe_set("r2.yaml", geometry__receivers=TWO_RX),
                 scenario_set("s.yaml", SCENARIO_LEARNED_YAML, recipe="r2.yaml")),
     message="row 'MDFNN': the checkpoint", klass="refusal",
     note="the line says 'expects 3 pairs (9 columns: ...); the scenario gives 2 pairs (6 columns: ...)'")
case("simulate/recipe-without-receivers", "simulate r.yaml --out new --quiet",
     setup=recipe_set(geometry__receivers=[]), message="r.yaml: recipe: need at least one transmitter",
     klass="refusal")
case("evaluate/recipe-without-receivers", "evaluate s.yaml --quiet --out out",
     setup=steps(recipe_set("r0.yaml", geometry__receivers=[]), scenario_set("s.yaml", recipe="r0.yaml")),
     message="r0.yaml: recipe: need at least one transmitter", klass="refusal")
case("train/recipe-without-receivers", f"{TR} --out run2 data.path=null data.recipe=r0.yaml",
     setup=recipe_set("r0.yaml", geometry__receivers=[]), message="r0.yaml: recipe: need at least one transmitter",
     klass="refusal")

# ---------------------------------------------------------------------------------------------
# demo (only cases that must be refused before any training starts)
# ---------------------------------------------------------------------------------------------
case("demo/out-user", "demo --out user", message="user", klass="data_loss")
case("demo/out-user-file", "demo --out user/notes.txt", message="notes.txt", klass="traceback")
case("demo/out-inside-file", "demo --out z.csv/d", message="z.csv", klass="traceback")
case("demo/out-cwd", "demo --out .", message="out", klass="data_loss")
case("demo/out-parent", "demo --out ..", message="out", klass="data_loss")
case("demo/out-dataset", "demo --out ds", message="ds", klass="data_loss")
case("demo/out-training-run", "demo --out run", message="run", klass="data_loss")
case("demo/out-symlink-to-user", "demo --out link", setup=LINK_USER, message="link", klass="data_loss")
case("demo/out-unwritable-sysfs", "demo --out locked/demo", setup=LOCK, message="locked", klass="traceback")
case("demo/out-folder-with-marker-and-user-files", "demo --out fake",
     setup=steps(write("fake/demo.json", '{"started": "2024-05-03 10:00:00"}\n'),
                 write("fake/thesis.tex", "\\chapter{Results}  % three months of work\n")),
     message="thesis.tex", timeout=30, klass="data_loss",
     note="a demo.json marker does not make the user's thesis.tex a demo output")
case("demo/sigterm-during-training", "demo --out dm --mc-runs 2", signal=("SIGTERM", 2.0),
     signal_after=("dm/train",), outputs=("dm",), timeout=120, klass="traceback",
     note="the unfinished demo folder stays (marked) and the line says the next demo replaces it")


def by_id() -> dict[str, Case]:
    return {c.id: c for c in CASES}


def _check() -> None:
    ids = [c.id for c in CASES]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    assert not dup, f"duplicate case ids: {dup}"
    for c in CASES:
        assert c.expect in ("refuse", "ok"), c.id
        assert c.root_expect in (None, "refuse", "ok"), c.id
        assert c.command in COMMANDS, c.id
        for a in c.argv:
            assert not a.startswith("/"), f"{c.id}: absolute path {a!r}"
            assert ".." not in Path(a).parts or a == "..", f"{c.id}: {a!r} leaves the sandbox"
        if c.signal is not None:
            assert c.signal[0] in ("SIGTERM", "SIGHUP", "SIGINT"), c.id


TBD_YAML = """\
name: tbd_tiny
mc_runs: 1
block_runs: 1
warmup_steps: 0
rd_maps:
  transmitters:
    - {name: SVN2, position_m: [-17745000.0, 1835500.0, 13077300.0], velocity_mps: [2229.2, -519.2, 2058.0]}
    - {name: SVN18, position_m: [6818700.0, -6090400.0, 18620300.0], velocity_mps: [1654.7, -2019.3, -926.3]}
  receiver_m: [0.0, 0.0, 0.0]
  snr_db: [12.0, 12.0]
  maps: {wavelength_m: 0.19, doppler_cell_hz: 10.0, altitude_m: 500.0}
  birth_box: {x_m: [4500.0, 5500.0], y_m: [2500.0, 3500.0], vx_mps: [-25.0, -15.0], vy_mps: [5.0, 15.0]}
methods:
  - {name: m, kind: modified_icmb, options: {particles_min: 50, particles_max: 200, birth_particles: 200}}
cases:
  - name: c
    targets: [{name: t, start_m: [5000.0, 3000.0], velocity_mps: [-20.0, 10.0], birth_s: 1.0,
               segments: [{duration_s: 2.0}]}]
    end_s: 4.0
"""
case("evaluate/tbd-ok", "evaluate t.yaml --out out", expect="ok", setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: None),
     outputs=("out",))
case("evaluate/tbd-receiver-million-numbers", "evaluate t.yaml --out out",
     setup=text_sub(TBD_YAML, "t.yaml", "receiver_m: [0.0, 0.0, 0.0]", "receiver_m: [" + "0," * 999_999 + "0]"),
     message="rd_maps.receiver_m (line 9) is a list of 1,000,000 values", klass="hang",
     note="three numbers expected; refused as it is read, not after building the list")
case("evaluate/tbd-receiver-four-numbers", "evaluate t.yaml --out out",
     setup=text_sub(TBD_YAML, "t.yaml", "receiver_m: [0.0, 0.0, 0.0]", "receiver_m: [0.0, 0.0, 0.0, 0.0]"),
     message="receiver_m", klass="refusal")
case("evaluate/tbd-unknown-snr-estimator", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d["methods"][0]["options"].update(snr_estimator="median")),
     message="option snr_estimator must be one of bootstrap, max", klass="refusal")
case("evaluate/tbd-subarea-larger-than-map", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d["methods"][0]["options"].update(subarea_half=400)),
     message="larger than the maps", klass="refusal")
case("evaluate/tbd-snr-nan", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d["rd_maps"].update(snr_db=[float("nan"), 12.0])),
     message="finite number", klass="refusal")
case("evaluate/tbd-particles-min-above-max", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d["methods"][0]["options"].update(particles_min=500)),
     message="particles_min (500)", klass="refusal")
case("evaluate/tbd-birth-box-outside-map", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d["rd_maps"].update(map_extent={"range_m": [0.0, 3000.0],
                                                                                   "doppler_hz": [-100.0, 100.0]})),
     message="outside the map's coverage", klass="refusal")
case("evaluate/tbd-unknown-update-order", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d["methods"][0]["options"].update(order="sideways")),
     message="order", klass="refusal")
case("evaluate/tbd-target-leaves-the-maps", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d["cases"][0]["targets"][0].update(start_m=[8000.0, 3000.0])),
     message="leaves the maps", klass="refusal")
case("evaluate/tbd-snr-list-length", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d["rd_maps"].update(snr_db=[8.0, 9.0, 10.0])),
     message="snr_db needs one value or one per map", klass="refusal")
case("evaluate/tbd-without-maps", "evaluate t.yaml --out out",
     setup=yaml_edit(TBD_YAML, "t.yaml", lambda d: d.pop("rd_maps")),
     message="add an rd_maps section", klass="refusal")
PHD_YAML = """\
name: phd_tiny
mc_runs: 1
block_runs: 1
world:
  scans: 6
  dimensions: 3
  geometry: {transmitters: [{position_m: [6500.0, 0.0], carrier_hz: 106.0e6}], receivers: [{position_m: [0.0, 0.0]}]}
  max_range_m: 48000.0
warmup_steps: 0
divergence_m: null
loss: {}
noise: {range_m: 30.0, range_rate_mps: 4.5}
detections:
  pd: 0.8
  components: [range, range_rate]
  clutter: {per_scan: 10, model: poisson, range_m: [6500.0, 48000.0], range_rate_mps: [-500.0, 500.0]}
methods: [{name: g, kind: smc_phd_pair, options: {particles_per_target: 50, particles_per_birth: 20}}]
cases:
  - name: c
    aircraft:
      - {name: a, start_m: [-9000.0, -5000.0], altitude_m: 9000.0, speed_mps: 220.0, heading_deg: 60.0,
         legs: [{duration_s: 6}]}
"""
case("evaluate/phd-ok", "evaluate p.yaml --out out", expect="ok", setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: None),
     outputs=("out",))
case("evaluate/phd-particles-per-target-below-10", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(particles_per_target=9)),
     message="option particles_per_target must be an integer in [10", klass="refusal")
case("evaluate/phd-birth-without-mass", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(birth_rate=0.0)),
     message="option birth_rate must be a number in", klass="refusal")
case("evaluate/phd-births-unknown", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(births="sometimes")),
     message="option births must be one of adaptive, every_detection", klass="refusal")
case("evaluate/phd-birth-particles-min-below-10", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(birth_particles_min=5)),
     message="option birth_particles_min must be an integer in [10", klass="refusal")
case("evaluate/phd-forgetting-zero", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(forgetting=0.0)),
     message="option forgetting must be a number in", klass="refusal")
case("evaluate/phd-forgetting-above-one", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(forgetting=1.5)),
     message="option forgetting must be a number in", klass="refusal")
case("evaluate/phd-pair-out-of-range", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d["methods"][0]["options"].update(pair=1)),
     message="pair 1 is out of range", klass="refusal")
case("evaluate/phd-study-file", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d.update(kind="phd")),
     message="'kind: phd' study files are gone", klass="refusal")
case("evaluate/phd-aircraft-never-seen", "evaluate p.yaml --out out",
     setup=yaml_edit(PHD_YAML, "p.yaml", lambda d: d["cases"][0]["aircraft"][0].update(altitude_m=50.0)),
     message="aircraft 'a' is never seen", klass="refusal")

# ---------------------------------------------------------------------------------------------
# issue 59 round three: evaluate's refusals that now name what the user asked for
# ---------------------------------------------------------------------------------------------
WITH_BOUND = SCENARIO_YAML + "  - {name: PCRB, kind: pcrb}\n"
case("evaluate/bound-row-alone", "evaluate b.yaml --methods PCRB --out out", expect="ok",
     setup=write("b.yaml", WITH_BOUND), outputs=("out",),
     note="--methods PCRB: the bound's row alone (it reads no product, so no random_streams question)")
case("evaluate/seed-of-5000-digits", ("evaluate", "sc.yaml", "--seed", "9" * 5000, "--out", "out"),
     message="expected a non-negative integer of at most 4,300 digits, got '99999999999999999999'... (5,000 characters)",
     klass="refusal", note="the line quotes the start of the argument and its length, not 5,000 digits")
case("evaluate/mc-runs-of-5000-characters", ("evaluate", "sc.yaml", "--mc-runs", "x" * 5000, "--out", "out"),
     message="expected a positive integer, got 'xxxxxxxxxxxxxxxxxxxx'... (5,000 characters)", klass="refusal")
case("evaluate/management-options-on-a-row-handed-its-births", "evaluate m.yaml --out out",
     setup=scenario_method("m.yaml", {"name": "J", "kind": "s_msjpda", "options": {"confirm_m": 9, "confirm_n": 3}}),
     message="option(s) confirm_m, confirm_n are read only with initiation: detections, and this row has "
             "initiation: oracle", klass="silent_wrong",
     note="ignored, they were recorded in results.json as the row's settings")
case("evaluate/bias-options-without-the-bias-test", "evaluate m.yaml --out out",
     setup=scenario_method("m.yaml", {"name": "J", "kind": "s_msjpda",
                                      "options": {"initiation": "detections", "bias_burn_in": 5}}),
     message="option(s) bias_burn_in are read only with bias_window not null", klass="silent_wrong")
case("evaluate/merge-probability-without-merging", "evaluate m.yaml --out out",
     setup=scenario_method("m.yaml", {"name": "J", "kind": "s_msjpda",
                                      "options": {"initiation": "detections", "merge_probability": 0.9}}),
     message="option(s) merge_probability are read only with merge_scans not null", klass="silent_wrong")
case("evaluate/init-scans-out-of-range", "evaluate m.yaml --out out",
     setup=scenario_method("m.yaml", {"name": "J", "kind": "s_msjpda",
                                      "options": {"initiation": "detections", "init_scans": 4}}),
     message="option init_scans must be an integer in [1, 3]", klass="refusal")
case("evaluate/init-scan-gate-without-multi-scan", "evaluate m.yaml --out out",
     setup=scenario_method("m.yaml", {"name": "J", "kind": "s_msjpda",
                                      "options": {"initiation": "detections", "init_scan_gate_probability": 0.99}}),
     message="option(s) init_scan_gate_probability are read only with init_scans: 2 | 3", klass="silent_wrong")
case("evaluate/targets-empty", "evaluate e.yaml --out out",
     setup=yaml_edit(SCENARIO_YAML, "e.yaml", lambda d: d["cases"].__setitem__(0, {"name": "steady", "targets": []})),
     message="case 'steady': targets: [] lists no target; give at least one", klass="refusal",
     note="was a single-target hint (needs start_range_m, ...) for a case that asked for no target")
case("evaluate/states-empty", "evaluate e.yaml --out out",
     setup=yaml_edit(SCENARIO_YAML, "e.yaml", lambda d: d["cases"].__setitem__(0, {"name": "steady", "states": []})),
     message="case 'steady': states: [] lists no target", klass="refusal")

_check()
