"""The bridge's parameter store (CiA 301 1010h "store parameters", 1011h "restore default
parameters"): one file beside the bridge's configuration.

1010h:01 = "save" (0x65766173) writes the raw values of the objects of
:data:`bridge.od.STORED` (the EDS marks them ``StorageLocation=PERSIST``) to the file; a
bridge started with that file applies them over the axis file's values
(:meth:`bridge.objects.ObjectServer.apply_stored`, validated together like one write, so a
file the bridge would refuse stops the start with :class:`~bridge.errors.StoreError`).
1011h:01 = "load" (0x64616F6C) removes the file: the defaults (axis file) apply at the next
start, as CiA 301 says ("restored parameters are valid after reset or power-up").

File format (JSON, UTF-8)::

    {"format": "backlash-bridge parameter store", "version": 1,
     "objects": {"2000h:00": "0000c841", ...},   # raw SDO bytes, hex, little-endian
     "readable": {"2000h:00": "Position loop gain kv = 25 1/s", ...}}

``objects`` is what a bridge loads. ``readable`` says the same values as a person reads them
(name, decoded value, unit), for someone opening the file; it is written, never read: an edit
there changes nothing (edit the value over SDO and store it again, or remove the file).

Writes are atomic (:func:`virtual_bus.atomic.write_atomic`, durable): a temporary file in the
same directory (``.NAME.XXXXXXXX.tmp``), fsync'ed, renamed over the store, then the directory
fsync'ed -- a kill or a power loss at any moment leaves the old store or the new one, never
neither and never half of one (a kill before the rename also leaves the temporary file).
"""

from __future__ import annotations

import contextlib
import json
import re
from collections.abc import Mapping
from pathlib import Path

from virtual_bus.atomic import fsync_directory, write_atomic

from .errors import StoreError

FORMAT = "backlash-bridge parameter store"
VERSION = 1
_KEY = re.compile(r"^([0-9A-F]{4})h:([0-9A-F]{2})$")

RawValues = dict[tuple[int, int], bytes]


def _key(index: int, subindex: int) -> str:
    return f"{index:04X}h:{subindex:02X}"


class ParameterStore:
    """The store file at ``path`` (see the module docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def save(
        self, values: RawValues, readable: Mapping[tuple[int, int], str] | None = None
    ) -> None:
        """Write ``values`` atomically (OSError if the directory is not writable), with
        ``readable``, each value as a person reads it, beside them (never read back)."""
        doc: dict[str, object] = {
            "format": FORMAT,
            "version": VERSION,
            "objects": {_key(i, s): raw.hex() for (i, s), raw in sorted(values.items())},
        }
        if readable:
            doc["readable"] = {_key(i, s): text for (i, s), text in sorted(readable.items())}
        write_atomic(self.path, json.dumps(doc, indent=1) + "\n", durable=True)

    def clear(self) -> None:
        """Remove the file (restore defaults at the next start); absent is fine."""
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
            fsync_directory(self.path.parent)  # the removal survives a power loss too

    def load(self) -> RawValues | None:
        """The stored raw values, None when there is no file; StoreError if malformed."""
        where = str(self.path)
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError) as exc:
            raise StoreError(
                f"{where}: cannot read the parameter store ({exc})", path=where
            ) from None
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise StoreError(
                f"{where}: not a parameter store (invalid JSON: {exc})", path=where
            ) from None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise StoreError(f"{where}: not a parameter store (format != {FORMAT!r})", path=where)
        if doc.get("version") != VERSION:
            raise StoreError(
                f"{where}: store version {doc.get('version')!r}; this bridge reads {VERSION}",
                path=where,
            ) from None
        objects = doc.get("objects")
        if not isinstance(objects, dict):
            raise StoreError(f"{where}: 'objects' must be a table of raw values", path=where)
        values: RawValues = {}
        for key, raw in objects.items():
            match = _KEY.match(key)
            if match is None or not isinstance(raw, str):
                raise StoreError(
                    f"{where}: entry {key!r}: expected 'IIIIh:SS' = hex bytes", path=where
                ) from None
            try:
                values[(int(match[1], 16), int(match[2], 16))] = bytes.fromhex(raw)
            except ValueError:
                raise StoreError(
                    f"{where}: entry {key}: {raw!r} is not hex bytes", path=where
                ) from None
        return values
