"""Signals as exceptions: SIGINT, SIGTERM and SIGHUP raise :class:`~pmsr_nn.errors.Interrupted`.

Raising (instead of dying) lets every ``with atomic_folder(...)`` block remove its temporary
folder on the way out, so an interrupted command leaves nothing half-written; the ``pmsr``
command then prints one line and exits with ``128 + signal number``, as a shell does.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from .errors import Interrupted

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

_received: int | None = None


def _raise(signum, frame):
    global _received
    _received = signum
    # A second signal while cleaning up is ignored: the first one's clean-up must finish.
    for s in SIGNALS:
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


def check() -> None:
    """Raise :class:`Interrupted` if a signal arrived whose exception was swallowed.

    Python runs a signal handler between two bytecodes of the main thread; when those belong to
    a weakref callback or a ``__del__``, the exception it raises is printed and dropped. Long
    loops and every commit of an output call this, so such a signal still stops the command
    before anything is published.
    """
    if _received is not None:
        raise Interrupted(_received)


@contextmanager
def signals_raise() -> Iterator[None]:
    """Within the block, the signals above raise :class:`Interrupted` (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    global _received
    _received = None
    before = {s: signal.getsignal(s) for s in SIGNALS}
    for s in SIGNALS:
        if before[s] is not signal.SIG_IGN:  # e.g. nohup: keep ignoring SIGHUP
            signal.signal(s, _raise)
    try:
        yield
    finally:
        for s, h in before.items():
            signal.signal(s, h if h is not None else signal.SIG_DFL)
        _received = None
