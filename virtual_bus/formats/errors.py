"""Exceptions of the file formats the whole project shares: one root, each subclass also
the matching builtin; and :func:`read_text`, how every format reads a file's text."""

from __future__ import annotations

from pathlib import Path


class FormatError(Exception):
    """Root of every error raised while reading or checking a shared file format."""


class AxisFileError(FormatError, ValueError):
    """An axis file (``docs/axis-file.md``) is malformed or non-physical.

    ``key`` is the dotted key (``"mechanics.load_mass"``) or section, ``value`` what was found.
    """

    def __init__(self, message: str, *, key: str | None = None, value: object = None) -> None:
        super().__init__(message)
        self.key = key
        self.value = value


class TraceFileError(FormatError, ValueError):
    """A servo trace (``docs/trace-file.md``) is malformed; ``column`` / ``row`` name where."""

    def __init__(self, message: str, *, column: str | None = None, row: int | None = None) -> None:
        super().__init__(message)
        self.column = column
        self.row = row


class DriveProfileError(FormatError, ValueError):
    """A drive profile (``config/drives/*.toml``, docs/commissioning.md) is unreadable or has
    a bad key (``path``, ``key`` attributes)."""

    def __init__(self, message: str, *, path: str = "", key: str = "") -> None:
        super().__init__(message)
        self.path = path
        self.key = key


class TraceWarning(UserWarning):
    """A trace column looks implausible for its unit (never rescaled silently)."""


class TornTailWarning(UserWarning):
    """A file of records (a trace, a candump log) ends in one its writer did not finish (a
    kill, a power loss, a full disk mid-write): readers keep every whole record before it and
    drop the tail, naming the file, the byte where it starts and its length."""


def read_text(path: Path, what: str, error: type[FormatError]) -> str:
    """The text of the file ``path`` holding ``what`` ("axis file"): UTF-8, a byte-order mark
    (an editor's or a spreadsheet's export) dropped; ``error`` in one line naming the file
    when it is missing, unreadable or not UTF-8."""
    return decode_text(read_bytes(path, what, error), path, what, error)


def read_bytes(path: Path, what: str, error: type[FormatError]) -> bytes:
    """The bytes of the file ``path`` holding ``what``; ``error`` in one line naming the file
    when it is missing or unreadable."""
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: no such {what}") from None
    except OSError as exc:
        raise error(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None


def decode_text(data: bytes, path: Path, what: str, error: type[FormatError]) -> str:
    """``data`` read from ``path`` as UTF-8 text, a byte-order mark dropped; ``error`` naming
    the first byte that is not UTF-8."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(
            f"{path}: byte {exc.start} (0x{exc.object[exc.start]:02X}) is not UTF-8; "
            f"{what}s are UTF-8 text"
        ) from None
