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
