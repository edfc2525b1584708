"""Is a file an EDS (or DCF) at all? The check a command makes before it opens a bus.

An Electronic Data Sheet is CiA 306: an INI file with ``[FileInfo]`` (``EDSVersion``),
``[DeviceInfo]``, the object lists (``[MandatoryObjects]`` first, which names 1000h, 1001h
and 1018h) and a section per object (``[1000]``, ``[1018sub2]``). A DCF is the same with a
``[DeviceComissioning]`` section. python canopen's ``import_od`` reads almost any INI file
and makes an empty or half object dictionary of it: a TOML file renamed ``fake.eds`` was
"read", and ``bridge probe`` then blamed the drive for six objects it could not map.
:func:`check_eds_file` refuses such a file in one line that names what is missing and what
an EDS has, before anything else happens (:class:`EdsFileError`, exit 2 in the commands).

It checks what makes a file an EDS, not every rule of CiA 306 (``tests/config`` checks the
project's own EDS files against the standard in full): vendor files with their quirks
(CRLF, a byte-order mark, lower-case hex, comments in Latin-1) pass.
"""

from __future__ import annotations

import ast
import configparser
import contextlib
import re
from pathlib import Path

from .errors import FormatError

#: What an EDS has (CiA 306), as the refusal says it.
WHAT_AN_EDS_HAS = (
    "an EDS (CiA 306) has [FileInfo], [DeviceInfo], [MandatoryObjects] and the object "
    "sections [1000], [1001], [1018]"
)
_OBJECT = re.compile(r"[0-9A-Fa-f]{4}(sub[0-9A-Fa-f]{1,2})?")
_MANDATORY = ("1000", "1001", "1018")


class EdsFileError(FormatError, ValueError):
    """A file given as an EDS is not one (``path``, ``reason`` attributes)."""

    def __init__(self, message: str, *, path: str, reason: str) -> None:
        super().__init__(message)
        self.path = path
        self.reason = reason


def _refuse(path: Path, reason: str) -> EdsFileError:
    return EdsFileError(
        f"{path}: not an EDS: {reason}; {WHAT_AN_EDS_HAS}", path=str(path), reason=reason
    )


def check_eds_file(path: str | Path) -> None:
    """Raise :class:`EdsFileError` (one line) unless ``path`` is an EDS or DCF by its
    structure (module docstring)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise EdsFileError(f"{path}: no such EDS file", path=str(path), reason="missing") from None
    except OSError as exc:
        raise EdsFileError(
            f"{path}: cannot read the EDS ({exc.strerror or exc})",
            path=str(path),
            reason="unreadable",
        ) from None
    if b"\x00" in raw:
        raise _refuse(path, "it holds NUL bytes (a binary file)")
    text = raw.decode("latin-1").removeprefix("\xef\xbb\xbf")
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    try:
        parser.read_string(text, source=str(path))
    except configparser.MissingSectionHeaderError as exc:
        raise _refuse(
            path, f"line {exc.lineno} {exc.line.strip()!r} is outside any section"
        ) from None
    except configparser.ParsingError as exc:
        lineno, line = exc.errors[0]  # the line as its repr
        with contextlib.suppress(ValueError, SyntaxError):
            line = ast.literal_eval(line)
        raise _refuse(path, f"line {lineno} {line.strip()!r} is no INI key = value") from None
    except configparser.Error as exc:
        first = str(exc).splitlines()[0]
        raise _refuse(path, f"not an INI file of sections and keys ({first})") from None
    sections = {s.lower(): s for s in parser.sections()}
    for required in ("FileInfo", "DeviceInfo", "MandatoryObjects"):
        if required.lower() not in sections:
            found = ", ".join(f"[{s}]" for s in parser.sections()[:4]) or "no sections"
            raise _refuse(path, f"no [{required}] section (found {found})")
    info = parser[sections["fileinfo"]]
    version = next((v for k, v in info.items() if k.lower() == "edsversion"), None)
    if version is not None and not re.fullmatch(r"\s*[34](\.\d+)?\s*", version):
        raise _refuse(path, f"[FileInfo] EDSVersion = {version.strip()!r}, CiA 306 is 4.0")
    objects = {s.upper() for s in parser.sections() if _OBJECT.fullmatch(s)}
    missing = [f"[{m}]" for m in _MANDATORY if m not in objects]
    if missing:
        raise _refuse(path, f"no object section {', '.join(missing)} (mandatory, CiA 301)")
