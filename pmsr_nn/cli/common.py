"""What every ``pmsr`` command shares: the parser class, the argument types and the one error path.

An anticipated failure (a bad recipe, path, dataset, checkpoint or device; a file that cannot be
read or written; memory) becomes one line ``pmsr: error: ...`` and exit code 2; anything else is
a bug: one line with a hint, exit code 1 (:func:`describe_error`), which names the method kind
and module of another package where its code raised it.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import PmsrError


def int_at_least(minimum: int, what: str, maximum: int | None = None):
    """An argparse type: an integer in ``[minimum, maximum]`` with a one-line error otherwise."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None and text.strip().isdigit():  # Python reads at most sys.get_int_max_str_digits() digits
            raise argparse.ArgumentTypeError(f"expected a {what} integer of at most {sys.get_int_max_str_digits():,} "
                                             f"digits, got {shown(text)}")
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected a {what} integer, got {shown(text)}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"at most {maximum:,}, got {shown(text)}")
        return value

    return parse


def shown(text: str, limit: int = 40) -> str:
    """``text`` quoted as the user typed it, or its start and its length where longer than ``limit``."""
    return repr(text) if len(text) <= limit else f"{text[:limit - 20]!r}... ({len(text):,} characters)"


positive_int = int_at_least(1, "positive")
nonneg_int = int_at_least(0, "non-negative")
mc_runs_int = int_at_least(1, "positive", maximum=10_000_000)  # MAX_MC_RUNS of the scenarios


class Parser(argparse.ArgumentParser):
    """argparse with its errors as one ``pmsr: error:`` line, like every other error of the command."""

    def error(self, message: str):
        self.exit(2, f"pmsr: error: {message} (see '{self.prog} --help')\n")


def describe_error(exc: BaseException) -> tuple[int, str]:
    """``(exit code, one line)`` for an exception escaping a command: 2 for anticipated failures
    (user input, files, resources), 1 for anything else (a bug: rerun with --debug)."""
    import errno

    if isinstance(exc, PmsrError):
        return 2, one_line(str(exc))
    if isinstance(exc, OSError):
        from ..outputs import virtual_file_system

        what = exc.strerror or str(exc) or type(exc).__name__
        where = f": {exc.filename}" if exc.filename else ""
        if exc.errno == errno.ENOSPC:
            what = "no space left on the device"
        virtual = virtual_file_system(exc.filename) if isinstance(exc.filename, str) else None
        if virtual is not None:  # e.g. a run folder under /proc: 'No such file or directory' says nothing useful
            return 2, one_line(f"{exc.filename}: {virtual} is a virtual file system with no disk behind it (like /proc "
                               "or /sys); give a folder on a disk")
        return 2, one_line(f"{what}{where}")
    if isinstance(exc, UnicodeError):
        return 2, one_line(f"a file is not UTF-8 text ({exc})")
    if isinstance(exc, MemoryError) or (isinstance(exc, RuntimeError) and "alloc" in str(exc).lower()):
        return 2, "out of memory; ask for less (fewer --tracks, --mc-runs or a smaller batch)"
    first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else ""
    said = f"unexpected {type(exc).__name__}" + (f": {first}" if first else "")
    plugin = plugin_at_fault(exc)
    if plugin is not None:  # raised in a method kind registered outside pmsr_nn: not pmsr_nn's bug
        return 1, one_line(f"{said}, raised in {plugin}: rerun with --debug for the traceback and report it to "
                           "that code's authors")
    return 1, said + "; this is a bug in pmsr_nn: rerun with --debug for the traceback and report it"


def plugin_at_fault(exc: BaseException) -> str | None:
    """The method kind of another package whose code raised ``exc`` (:func:`pmsr_nn.methods.plugin_at_fault`);
    None when none did, or when no method kind was ever consulted (the registry not imported)."""
    methods = sys.modules.get("pmsr_nn.methods")  # not imported: no method kind can have run
    return None if methods is None else methods.plugin_at_fault(exc)


def one_line(text: str, limit: int = 400) -> str:
    """``text`` with its whitespace runs as single spaces, cut to ``limit`` characters."""
    line = " ".join(text.split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def signal_name(signum: int) -> str:
    """``SIGINT``, ``SIGTERM``, ... for a signal number."""
    import signal

    return signal.Signals(signum).name
