"""Typed errors raised by the numerical library.

The service maps each class to an HTTP status; library users catch them like
any ``ValueError``.
"""


class OTGeoError(Exception):
    """Base class of every error the library raises on purpose.

    Parameters
    ----------
    message : str
        What went wrong, for a person to read.
    field : str, optional
        The offending input (e.g. ``"faces"``, ``"mu"``), so a caller can point at it.

    Attributes
    ----------
    message : str
        The message given.
    field : str or None
        The offending input, if known.
    """

    def __init__(self, message: str, *, field: str | None = None):
        super().__init__(message)
        self.message = message
        self.field = field


class InputError(OTGeoError, ValueError):
    """An argument is malformed: wrong shape, NaN, negative mass, out of range."""


class DomainError(InputError):
    """A domain cannot be built from the given geometry or connectivity."""


class MeshFormatError(DomainError):
    """A mesh file is empty, unreadable or of an unsupported format."""


class UnsupportedDomainError(InputError):
    """The operation cannot run on this domain (e.g. mass cannot cross components)."""


class ConvergenceError(OTGeoError):
    """An iterative solver could not produce a meaningful result."""


class CancelledError(OTGeoError):
    """A cancellation check requested the solver to stop."""
