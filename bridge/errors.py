"""Exceptions of :mod:`bridge`: one root, each subclass also the matching builtin.

Protocol codes travel as attributes: :class:`ParameterError` carries the CiA 301 SDO abort
code (:class:`virtual_bus.contract.SdoAbort`) an SDO server answers with,
:class:`DriveSetupError` the abort code the drive sent (if any) and the object that failed.
"""

from __future__ import annotations

from virtual_bus.contract import SdoAbort as SdoAbort


class BridgeError(Exception):
    """Root of every error raised on purpose by :mod:`bridge`."""


class BridgeConfigError(BridgeError, ValueError):
    """A configuration value (CLI argument, constructor argument) is out of its allowed range."""


class ParameterError(BridgeError, ValueError):
    """A parameter value (SDO write or configuration) is refused; nothing was changed.

    ``field``: the parameter's name, ``value``: what was given, ``abort_code``: the
    :class:`SdoAbort` an SDO server answers the write with.
    """

    def __init__(self, message: str, *, field: str, value: object, abort_code: SdoAbort) -> None:
        super().__init__(message)
        self.field = field
        self.value = value
        self.abort_code = abort_code


class MoveError(BridgeError, ValueError):
    """A move (command line, move file, target-position object) is malformed."""


class MoveFileError(MoveError):
    """A move file cannot be read or is malformed; ``path`` and ``line``/``entry`` name where."""

    def __init__(self, message: str, *, path: str, entry: int | None = None) -> None:
        super().__init__(message)
        self.path = path
        self.entry = entry


class PdoFrameError(BridgeError, ValueError):
    """A received PDO frame has the wrong length for the configured mapping."""

    def __init__(self, message: str, *, can_id: int, length: int, expected: int) -> None:
        super().__init__(message)
        self.can_id = can_id
        self.length = length
        self.expected = expected


class DriveSetupError(BridgeError, RuntimeError):
    """Configuring the drive over SDO or bringing it to Operation Enabled failed.

    ``index``/``subindex`` name the object (``None`` when not object-specific),
    ``abort_code`` the SDO abort code the drive answered with (``None`` for timeouts).
    ``problems``: when the start-up's plan found several things missing at once, one error
    per problem (this error names the first one's object); else empty.
    """

    def __init__(
        self,
        message: str,
        *,
        index: int | None = None,
        subindex: int | None = None,
        abort_code: int | None = None,
        problems: tuple[DriveSetupError, ...] = (),
    ) -> None:
        super().__init__(message)
        self.index = index
        self.subindex = subindex
        self.abort_code = abort_code
        self.problems = problems


class DriveTimeoutError(DriveSetupError, TimeoutError):
    """The drive did not answer (SDO response, state change, heartbeat) in time."""


class StoreError(BridgeConfigError):
    """The parameter store file (1010h) cannot be read, is malformed or holds values the
    bridge refuses; ``path`` names the file. The bridge does not start on it."""

    def __init__(self, message: str, *, path: str) -> None:
        super().__init__(message)
        self.path = path


class CommissionInputError(BridgeConfigError):
    """Commissioning input refused before anything is sent: an unknown object, a value of the
    wrong type or out of range, an unreadable DCF or EDS (exit status 2)."""


class NodeAccessError(BridgeError, RuntimeError):
    """A node refused an SDO request or did not answer (exit status 1).

    ``index``/``subindex`` name the object, ``abort_code`` is the node's SDO abort code
    (``None``: no answer)."""

    def __init__(
        self, message: str, *, index: int, subindex: int, abort_code: int | None = None
    ) -> None:
        super().__init__(message)
        self.index = index
        self.subindex = subindex
        self.abort_code = abort_code


class ContourError(BridgeError, ValueError):
    """A contour (path, feed, axis limits, circular test) is refused before any axis moves:
    a malformed segment or program line, a point outside an axis' travel limits, a feed or an
    acceleration above what the axes allow (bridge.contour)."""
