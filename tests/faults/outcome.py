"""What a fault case's outcome is: the classes of the census, shared by
``benchmarks/fault_census.py`` (subprocesses) and ``tests/test_bad_input.py`` (in-process).

Classes, in order of precedence: data_loss, hang, traceback, silent_wrong, leftover,
messy_refusal, clean_refusal, ok (see the census script's docstring).
"""

from __future__ import annotations

import os
import re

from .cases import Case

CLASSES = ("data_loss", "hang", "traceback", "silent_wrong", "leftover", "messy_refusal", "clean_refusal", "ok")
MEMORY_CAP = 6 << 30
MEMORY_PATTERNS = re.compile(r"MemoryError|Cannot allocate memory|can't allocate memory|std::bad_alloc|"
                             r"out of memory|DefaultCPUAllocator", re.IGNORECASE)
LEFTOVER_NAME = re.compile(r"\.partial|\.old-")
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def _under(rel_box: str, outputs: tuple[str, ...]) -> bool:
    """Whether ``rel`` (relative to the case folder) is one of the outputs (relative to the working
    folder CASE/box/work) or inside one."""
    for o in outputs:
        o = os.path.normpath(os.path.join("box", "work", o))
        if rel_box == o or rel_box.startswith(o + os.sep):
            return True
    return False


def classify(c: Case, expect: str, res: dict, changes: dict, verify_msg: str | None) -> tuple[str, str]:
    """``(class, reason)`` of one finished case."""
    rc, err = res["rc"], res["stderr"]
    lines = [ln for ln in err.strip().split("\n") if ln.strip()]
    signalled = c.signal is not None and res["signal_sent_at"] is not None
    prefix = "pmsr: " if signalled else "pmsr: error: "
    one_line = len(lines) == 1 and lines[0].startswith(prefix)
    clean_rc = (rc != 0) if signalled else (rc == 2)
    lost_ok = expect == "ok" and rc == 0   # a success may replace its outputs; nothing else may
    lost = [p for p in changes["removed"] + changes["modified"] if not (lost_ok and _under(p, c.outputs))]
    created = changes["created"]
    partials = [p for p in created if LEFTOVER_NAME.search(os.path.basename(p)) or LEFTOVER_NAME.search(p)]
    stray = [p for p in created if not _under(p, c.outputs)]
    half_written = [p for p in created if _under(p, c.outputs)] if (expect == "refuse" and not signalled) else []
    memory = (not one_line and bool(MEMORY_PATTERNS.search(err))) or (res["maxrss_mb"] or 0) > 0.95 * MEMORY_CAP / 2**20

    if lost:
        return "data_loss", f"{len(lost)} path(s) changed or removed outside the outputs: {_short(lost)}"
    if res["timed_out"]:
        return "hang", f"no exit after {res['seconds']:.0f} s"
    if memory:
        return "hang", f"memory exhausted (peak RSS {res['maxrss_mb']} MB): {_last_line(err)}"
    if "Traceback" in err:
        return "traceback", _last_line(err)
    if signalled and rc == 0:
        return "silent_wrong", "exit 0 although interrupted"
    if not signalled and rc not in (0, 2):
        return "traceback", f"exit code {rc}: {_last_line(err) or '(no stderr)'}"
    if expect == "refuse" and rc == 0:
        return "silent_wrong", "exit 0: the bad input was accepted" + (f"; created {_short(created)}" if created else "")
    if expect == "ok" and rc != 0:
        return "silent_wrong", f"refused a valid input: {_last_line(err)}"
    if expect == "ok":
        if verify_msg:
            return "silent_wrong", f"exit 0 but the output is wrong: {verify_msg}"
        if partials or stray:
            return "leftover", f"left {_short(partials or stray)}"
        return "ok", ""
    if partials or stray or half_written:
        return "leftover", f"left {_short(partials or stray or half_written)}" + ("" if one_line else " (and not one line)")
    if not clean_rc or not one_line:
        what = f"{len(lines)} stderr line(s)" if len(lines) != 1 else f"does not start with {prefix!r}"
        return "messy_refusal", f"exit {rc}, {what}: {_first_line(err)}"
    return "clean_refusal", lines[0][:200]


def _short(paths: list[str], n: int = 3) -> str:
    head = ", ".join(paths[:n])
    return head + (f" (+{len(paths) - n} more)" if len(paths) > n else "")


EXCEPTION_LINE = re.compile(r"^[A-Za-z_][\w.]*(Error|Exception|Exit|Interrupt|Warning)\b")


def _last_line(text: str) -> str:
    """The exception line of the last traceback (else the last line) of ``text``."""
    lines = [ln.strip() for ln in text.strip().split("\n") if ln.strip()]
    if "Traceback" in text:
        for ln in reversed(lines):
            if EXCEPTION_LINE.match(ln):
                return ln[:200]
    return lines[-1][:200] if lines else ""


def _first_line(text: str) -> str:
    lines = [ln.strip() for ln in text.strip().split("\n") if ln.strip()]
    return lines[0][:160] if lines else "(empty)"
