"""Files of records (lines) appended while a program runs -- the servo trace, the candump log
of the bus: how they are written so that a writer killed at any moment leaves whole records,
and how a reader finds where the whole records end (``docs/trace-file.md``, "What a kill
leaves").

Linux copies a ``write()`` into the page cache one page (4096 bytes, or a larger folio that
starts on a multiple of 4096) at a time and checks for a pending SIGKILL before each one
(``generic_perform_write``): a write a kill interrupts leaves the file ending on a multiple
of 4096 bytes inside it; a kill between writes leaves the file where a write ended.
:class:`RecordFile` writes whole lines in blocks, each block with as many ``write()`` calls
as it takes (a short write is finished, never dropped), and when a write fails (disk full)
it cuts the file back to the block's start. So the file ends after a whole line or on a
4096-byte boundary inside a block, nowhere else. Two ways to make that boundary harmless:

* ``pad=True`` (the candump log, read by programs the project does not own: python-can,
  can-utils): a line that would cross a 4096-byte boundary of the file is preceded by a
  padding line, spaces and a line end, that ends on the boundary (:func:`padded`). Every
  place a kill can cut is then the end of a line; candump readers skip blank lines.
* ``pad=False`` (the trace, read by the project's readers only): a cut can leave a last line
  without its line end. Every whole record has one, so a reader drops what follows the last
  line end (:func:`whole_lines_end`, :func:`torn_tail`) and warns once, naming the file, the
  byte where the dropped tail starts and its length (:class:`TornTailWarning`).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from pathlib import Path

from ..closing import Closing
from .errors import TornTailWarning

#: The boundary a kill can cut a write at: a page of the page cache (larger pages and folios
#: are multiples of it, so a file whose lines never cross it has none crossing theirs either).
PAGE_BYTES = 4096
#: Bytes read at a time when a reader looks for the last line end from the end of a file.
_TAIL_READ_BYTES = 1 << 16


def padding(nbytes: int) -> bytes:
    """A line of ``nbytes`` bytes that candump readers skip: spaces and a line end."""
    return b" " * (nbytes - 1) + b"\n"


def padded(data: bytes, offset: int, page: int = PAGE_BYTES) -> bytes:
    """``data`` (whole lines) as written at file offset ``offset``: before each line that
    would cross a multiple of ``page``, a padding line up to that boundary. A line longer than
    a page cannot stay inside one and is written as it is."""
    out: list[bytes] = []
    start, pos = 0, offset  # data[start:] is not emitted yet; it goes to file offset pos
    size = len(data)
    while True:
        boundary = (pos // page + 1) * page
        end = start + boundary - pos  # index in data of the byte at the boundary
        if end >= size:
            break
        if data[end - 1] == 0x0A:  # a line ends on the boundary
            out.append(data[start:end])
            start, pos = end, boundary
            continue
        line_start = data.rfind(b"\n", start, end) + 1 or start
        if line_start == start and pos % page == 0:  # one line longer than a page
            line_end = data.find(b"\n", end) + 1 or size
            out.append(data[start:line_end])
            start, pos = line_end, pos + line_end - start
            continue
        out.append(data[start:line_start])
        pos += line_start - start
        out.append(padding(boundary - pos))
        start, pos = line_start, boundary
    out.append(data[start:])
    return b"".join(out)


class RecordFile(Closing):
    """A new file (truncated if it exists) written in blocks of whole lines (see the module
    docstring). ``pad``: a line never crosses a :data:`PAGE_BYTES` boundary of the file."""

    def __init__(self, path: str | Path, *, pad: bool) -> None:
        self.path = Path(path)
        self._pad = pad
        flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_CLOEXEC", 0)
        self._fd = os.open(self.path, flags, 0o666)
        self._offset = 0
        self._closed = False

    @property
    def offset(self) -> int:
        """Bytes in the file: where the next block starts."""
        return self._offset

    @property
    def closed(self) -> bool:
        return self._closed

    def write_lines(self, lines: Sequence[str]) -> None:
        """Append ``lines`` (each ending in ``\\n``) as one block."""
        if lines:
            self.write("".join(lines).encode())

    def write(self, data: bytes) -> None:
        """Append ``data`` (whole lines) as one block; OSError (disk full, ...) leaves the
        file as it was before the block."""
        if self._closed:
            raise ValueError(f"{self.path}: write to a closed record file")
        if self._pad:
            data = padded(data, self._offset)
        view = memoryview(data)
        done = 0
        try:
            while done < len(view):
                done += os.write(self._fd, view[done:])  # may copy less than asked
        except BaseException:
            if done:
                try:  # no half block stays behind
                    os.ftruncate(self._fd, self._offset)
                    os.lseek(self._fd, self._offset, os.SEEK_SET)
                except OSError:
                    pass
            raise
        self._offset += done

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            os.close(self._fd)


# --- readers ------------------------------------------------------------------------------
def whole_lines_end(data: bytes) -> int:
    """Length of the whole lines at the start of ``data``: just past its last ``\\n``."""
    return data.rfind(b"\n") + 1


def file_whole_lines_end(path: Path) -> tuple[int, int]:
    """(length of the whole lines, size) of the file ``path``, reading only its tail."""
    with path.open("rb") as f:
        size = f.seek(0, os.SEEK_END)
        pos = size
        while pos > 0:
            step = min(_TAIL_READ_BYTES, pos)
            pos -= step
            f.seek(pos)
            found = f.read(step).rfind(b"\n")
            if found >= 0:
                return pos + found + 1, size
    return 0, size


def torn_tail(source: str, end: int, size: int, record: str) -> None:
    """Warn once (:class:`TornTailWarning`) that the ``size - end`` bytes of ``source`` from
    byte ``end`` on are a ``record`` without its line end, dropped; nothing when none are."""
    if end < size:
        warnings.warn(
            f"{source}: the last {size - end} bytes (from byte {end}) are a {record} without "
            "its line end, as a writer stopped mid-write leaves it: dropped, every whole "
            f"{record} before it is read",
            TornTailWarning,
            stacklevel=3,
        )
