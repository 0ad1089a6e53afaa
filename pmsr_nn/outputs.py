"""Safe outputs: every file and folder a ``pmsr`` command writes goes through here.

Rules, in the order they are checked (each breach is an :class:`~pmsr_nn.errors.OutputError`,
raised before anything is written):

* an output is never the working directory, one of its parents, the home folder or ``/``;
* an output is never an input of the same command, a folder holding one, or a path inside one;
* an output is never on a virtual file system (``/proc``, ``/sys``: no disk behind it);
* an existing folder is replaced only with ``overwrite`` and only when it carries our marker
  (:data:`MARKER`, written into every folder a command completes); where the marker lists the
  files the command wrote (every folder :func:`atomic_folder` completes), only when the folder
  holds nothing else (a file a user added to one of our outputs is never deleted); an existing
  file only with ``overwrite``; a symbolic link never (the link target would be what is replaced);
* the parent folder must exist or be creatable, and be writable.

Writing happens in a hidden temporary sibling ``.NAME.partial-PID`` (never inside the target),
which is flushed to disk and renamed onto the target only when complete, after the target is
checked again. A failure or a signal removes the temporary; a run killed outright (SIGKILL,
power loss) leaves it, and the next command writing the same target removes it once no live
process owns it (a temporary folder carries a marker that proves it is ours; a temporary file
cannot, and is left for the user). A replaced folder is
first renamed aside (``.NAME.old-PID``), so the target is never half old, half new.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from . import __version__, interrupts
from .errors import OutputError

MARKER = ".pmsr_output.json"
"""Written into every output folder a command completes: what wrote it, and when."""

PARTIAL_MARKER = ".pmsr_partial"
"""Written first into every temporary folder, so that only our own leftovers are ever removed."""

_PARTIAL = re.compile(r"^\.(?P<name>.+)\.(?:partial|old)-(?P<pid>\d+)$")


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(Path(path).expanduser()))


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (this one included; another user's counts as alive)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


DATASET_FORMAT = "pmsr_nn.track_dataset"
DATASET_MANIFEST = "manifest.json"
"""A dataset folder's manifest and its ``format`` (written by :mod:`pmsr_nn.data.store`; named here, below
the data layer, because datasets of earlier releases carry no marker and are known by their manifest)."""


def is_our_dataset(path: Path) -> bool:
    """True when ``path`` is a directory holding a dataset manifest of this format."""
    try:
        return json.loads((Path(path) / DATASET_MANIFEST).read_text()).get("format") == DATASET_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def output_kind(path: Path) -> str | None:
    """The ``pmsr`` command that wrote folder ``path`` (None: not ours, or not a folder).

    Our marker names it; datasets and demo folders of earlier releases are known by their own
    manifest (``simulate``) and ``demo.json`` (``demo``).
    """
    path = Path(path)
    if path.is_symlink() or not path.is_dir():
        return None
    try:
        marker = json.loads((path / MARKER).read_text())
        if isinstance(marker, dict) and marker.get("format") == "pmsr_nn.output":
            return str(marker.get("command"))
    except (OSError, ValueError):
        pass
    if is_our_dataset(path):
        return "simulate"
    try:
        return "demo" if isinstance(json.loads((path / "demo.json").read_text()), dict) else None
    except (OSError, ValueError):
        return None


def is_ours(path: Path) -> bool:
    """True when ``path`` is a folder some ``pmsr`` command wrote."""
    return output_kind(path) is not None


def write_marker(folder: Path, command: str, **facts) -> None:
    """Mark ``folder`` as written by ``pmsr COMMAND`` (so a later ``--overwrite`` may replace it)."""
    data = {"format": "pmsr_nn.output", "command": command, "pmsr_nn": __version__,
            "written": time.strftime("%Y-%m-%dT%H:%M:%S"), **facts}
    _write_synced(Path(folder) / MARKER, json.dumps(data, indent=1) + "\n")


def _write_synced(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all: a temporary beside it, synced, then renamed
    (a full disk leaves the earlier marker as it was, not an empty one)."""
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        f = open(tmp, "x", encoding="utf-8")  # created here or refused: a file of that name is never ours to remove
    except FileExistsError:
        raise OutputError(f"{path}: the temporary name {tmp} is taken; remove it if it is not yours") from None
    try:
        with f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)  # ours: created above, gone already where the rename took it


def check_target(out: Path, *, inputs: Iterable[Path] = (), what: str = "--out") -> Path:
    """Refuse output paths that are never safe to write (see the module docstring).

    Returns the absolute path. Does not look at whether ``out`` exists (only at the file system it
    would be on).
    """
    target = _resolved(out)
    cwd = _resolved(Path.cwd())
    real, real_cwd = Path(os.path.realpath(target)), Path(os.path.realpath(cwd))
    if target == cwd or target in cwd.parents or real == real_cwd or real in real_cwd.parents:
        raise OutputError(f"{what} {out} is the working directory or a parent of it; give a new folder inside it")
    if target == _resolved(Path.home()) or target == Path(target.anchor):
        raise OutputError(f"{what} {out} is the home folder or the file-system root; give a new folder")
    for given in inputs:
        src = Path(os.path.realpath(_resolved(given)))
        if real == src:
            raise OutputError(f"{what} {out} is also an input of this command; choose another output")
        if real in src.parents:
            raise OutputError(f"{what} {out} holds the input {given}; choose another output")
        if src in real.parents:
            raise OutputError(f"{what} {out} lies inside the input {given}; choose another output")
    virtual = virtual_file_system(target)
    if virtual is not None and not _can_create_in(virtual):  # root may write to /proc and /sys, yet nothing is stored
        raise OutputError(f"{what} {out}: {virtual} is a virtual file system with no disk behind it (like /proc or "
                          "/sys); give a folder on a disk")
    return target


def _nearest_existing(path: Path) -> Path:
    anc = _resolved(path)
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    return anc


def virtual_file_system(path: str | Path) -> Path | None:
    """The nearest existing ancestor of ``path`` when it lies on a file system with no disk behind
    it (``/proc``, ``/sys``: no blocks at all), else None."""
    anc = _nearest_existing(Path(path))
    try:
        return anc if shutil.disk_usage(anc).total == 0 else None
    except OSError:
        return None


def _check_parent(out: Path, what: str) -> None:
    """The nearest existing ancestor of ``out`` must be a writable folder."""
    anc = _resolved(out).parent
    while not anc.exists():
        if anc.is_symlink():
            raise OutputError(f"{what} {out}: {anc} is a broken symbolic link")
        anc = anc.parent
    if not anc.is_dir():
        raise OutputError(f"{what} {out}: {anc} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {out}: no permission to write in {anc}")


def _can_create_in(folder: Path) -> bool:
    """Whether a folder can be created (and is removed again) in ``folder``: a file system that
    reports no blocks may still be a writable one (ramfs)."""
    try:
        probe = tempfile.mkdtemp(prefix=".pmsr-probe-", dir=folder)
    except OSError:
        return False
    os.rmdir(probe)
    return True


def check_folder_target(out: Path, *, overwrite: bool, inputs: Iterable[Path] = (), what: str = "--out",
                        allow: Iterable[str] = ()) -> None:
    """Everything :func:`atomic_folder` checks, without writing: call it before long work.

    ``allow``: commands whose marked folders this one may replace (default: any of ours).
    """
    out = Path(out)
    check_target(out, inputs=inputs, what=what)
    if out.is_symlink():
        raise OutputError(f"{what} {out} is a symbolic link; give the real folder or a new path")
    if out.exists():
        if not out.is_dir():
            raise OutputError(f"{what} {out} exists and is a file, not a folder")
        if any(out.iterdir()):
            kind = output_kind(out)
            if kind is None:
                raise OutputError(f"{what} {out} exists and was not written by pmsr (no {MARKER}); pmsr never "
                                  "replaces what it did not write: choose another path")
            allowed = tuple(allow)
            if allowed and kind not in allowed:
                raise OutputError(f"{what} {out} holds the output of 'pmsr {kind}', not of 'pmsr {allowed[0]}'; "
                                  "choose another path")
            if not overwrite:
                raise OutputError(f"{what} {out} already exists; pass --overwrite to replace it")
            foreign = foreign_files(out)
            if foreign:
                more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
                raise OutputError(f"{what} {out} holds files pmsr did not write ({', '.join(foreign[:3])}{more}); pmsr "
                                  "never deletes what it did not write: move them out or choose another path")
    _check_parent(out, what)


def folder_contents(folder: Path) -> list[str]:
    """Every file and folder under ``folder``, as sorted relative POSIX paths (our marker aside)."""
    folder = Path(folder)
    out = []
    for dirpath, dirs, files in os.walk(folder):
        rel = Path(dirpath).relative_to(folder)
        out += [(rel / name).as_posix() for name in dirs + files]
    return sorted(p for p in out if p != MARKER)


def foreign_files(folder: Path) -> list[str]:
    """What ``folder`` holds beyond the files its marker says our command wrote (empty where the
    marker lists none: folders of earlier releases, or of commands that write as they go)."""
    try:
        marker = json.loads((Path(folder) / MARKER).read_text())
    except (OSError, ValueError):
        return []
    listed = marker.get("contents") if isinstance(marker, dict) else None
    if not isinstance(listed, list):
        return []
    known = set(listed)
    return [p for p in folder_contents(folder) if p not in known]


def clean_stale(out: Path) -> list[Path]:
    """Remove our temporary folders for target ``out`` whose process is gone (each carries our
    partial or output marker); returns what was removed."""
    out = _resolved(out)
    parent = out.parent
    removed = []
    if not parent.is_dir():
        return removed
    for p in parent.iterdir():
        m = _PARTIAL.match(p.name)
        if not m or m["name"] != out.name or process_alive(int(m["pid"])):
            continue
        # A folder proves it is ours by its marker; a file cannot, so a stale temporary file stays.
        if p.is_dir() and not p.is_symlink() and ((p / PARTIAL_MARKER).exists() or is_ours(p)):
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    return removed


def make_parents(out: Path) -> list[Path]:
    """Create the missing parents of ``out``; return them, outermost first (to undo on failure)."""
    made = []
    anc = _resolved(out).parent
    missing = []
    while not anc.exists():
        missing.append(anc)
        anc = anc.parent
    for d in reversed(missing):
        d.mkdir()
        made.append(d)
    return made


def remove_if_empty(folders: list[Path]) -> None:
    for d in reversed(folders):
        try:
            d.rmdir()
        except OSError:
            break


def _fsync_tree(root: Path) -> None:
    for dirpath, _, files in os.walk(root):
        for name in files:
            try:
                fd = os.open(os.path.join(dirpath, name), os.O_RDONLY)
            except OSError:
                continue
            try:
                os.fsync(fd)
            finally:
                os.close(fd)


@contextmanager
def atomic_folder(out: Path, *, command: str, overwrite: bool = False, inputs: Iterable[Path] = (),
                  what: str = "--out", allow: Iterable[str] = (), **facts) -> Iterator[Path]:
    """Yield a temporary folder that becomes ``out`` (with our marker) only if the block completes."""
    out = Path(out)
    inputs = list(inputs)
    check_folder_target(out, overwrite=overwrite, inputs=inputs, what=what, allow=allow)
    made = make_parents(out)
    clean_stale(out)
    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    try:
        tmp.mkdir()  # fails if the name exists: then nothing below may remove it
    except OSError as exc:
        remove_if_empty(made)
        raise OutputError(f"{what} {out}: cannot create the temporary folder {tmp} ({exc.strerror})") from None
    try:
        (tmp / PARTIAL_MARKER).touch()
        yield tmp
        interrupts.check()
        # The work may have taken hours: what is at ``out`` now must still be ours to replace.
        check_folder_target(out, overwrite=overwrite, inputs=inputs, what=what, allow=allow)
        (tmp / PARTIAL_MARKER).unlink()
        write_marker(tmp, command, contents=folder_contents(tmp), **facts)
        _fsync_tree(tmp)
        replace_folder(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        remove_if_empty(made)
        raise


def replace_folder(src: Path, out: Path) -> None:
    """Rename ``src`` onto ``out``; an existing ``out`` (already checked to be ours) is moved aside first."""
    if out.is_dir() and not out.is_symlink():
        if any(out.iterdir()):
            old = out.parent / f".{out.name}.old-{os.getpid()}"
            out.rename(old)
            src.rename(out)
            shutil.rmtree(old, ignore_errors=True)
            return
        out.rmdir()
    src.rename(out)


def check_file_target(path: Path, *, overwrite: bool, inputs: Iterable[Path] = (), what: str = "--out",
                      suffixes: tuple[str, ...] = ()) -> None:
    """Everything :func:`atomic_file` checks, without writing."""
    path = Path(path)
    check_target(path, inputs=inputs, what=what)
    if suffixes and path.suffix.lower() not in suffixes:
        raise OutputError(f"{what} {path} must end in {' or '.join(suffixes)}")
    if path.is_symlink():
        raise OutputError(f"{what} {path} is a symbolic link; give a plain file path")
    if path.exists():
        if path.is_dir():
            raise OutputError(f"{what} {path} is a folder; give a file path")
        if not overwrite:
            raise OutputError(f"{what} {path} already exists; pass --overwrite to replace it")
    parent = _resolved(path).parent
    if not parent.exists():
        raise OutputError(f"{what} {path}: folder {path.parent} does not exist")
    _check_parent(path, what)


@contextmanager
def atomic_file(path: Path, *, overwrite: bool = False, inputs: Iterable[Path] = (), what: str = "--out",
                suffixes: tuple[str, ...] = ()) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` that replaces it (synced) only if the block completes."""
    path = Path(path)
    check_file_target(path, overwrite=overwrite, inputs=inputs, what=what, suffixes=suffixes)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    if tmp.exists() or tmp.is_symlink():
        raise OutputError(f"{what} {path}: the temporary name {tmp} is taken; remove it if it is not yours")
    try:
        yield tmp
        interrupts.check()
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
