"""Errors raised on bad user input.

Every error a user can cause derives from :class:`PmsrError`; the ``pmsr`` command prints
its message on one line and exits non-zero instead of showing a traceback.
"""


class PmsrError(Exception):
    """Base class of all user-facing errors of the package."""


class ConfigError(PmsrError, ValueError):
    """A recipe or config is invalid: unknown key, wrong type, value out of range."""


class GeometryError(PmsrError, ValueError):
    """The sensor geometry is invalid (e.g. a receiver on top of a transmitter)."""


class DatasetError(PmsrError):
    """A dataset on disk is missing, foreign, incomplete or corrupted."""


class CheckpointError(PmsrError):
    """A checkpoint is missing, truncated, foreign, or made for another geometry or layout."""


class MeasurementError(PmsrError, ValueError):
    """Measurements given to a tracker have the wrong shape or columns, NaNs, or are too short."""


class OutputError(PmsrError):
    """An output path is unsafe (an input, the working directory, a folder pmsr did not write) or unwritable."""


class Interrupted(BaseException):
    """A signal (SIGINT, SIGTERM, SIGHUP) asked the command to stop.

    A ``BaseException`` like ``KeyboardInterrupt``, so that ``except Exception`` blocks do not
    swallow it, but not a subclass of it: Lightning turns a ``KeyboardInterrupt`` during
    ``fit`` into ``sys.exit(1)``, which would hide the signal.
    """

    def __init__(self, signum: int):
        import signal

        self.signum = int(signum)
        self.name = signal.Signals(signum).name
        super().__init__(self.name)
