"""Files written whole (a figure, a summary, a table, the parameter store): a kill at any
moment leaves the file that was there before (or none) or the complete new one, never a part.

The new content goes to a temporary file in the same folder (``.NAME.XXXXXXXX.tmp``: hidden,
and no reader's pattern matches it) that is renamed over the file when complete (``rename``
replaces a name atomically on one file system). A kill before the rename leaves that
temporary file behind beside the old one. ``durable=True`` (the parameter store) also
fsyncs the file before the rename and the folder after it, so a power loss leaves the old or
the new content as well; without it a power loss leaves what the file system kept.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def replacing(path: Path, *, durable: bool = False) -> Iterator[Path]:
    """A temporary path to write the new content of ``path`` to; renamed over ``path`` when
    the block ends normally, removed when it raises. The temporary name ends in ``.tmp``:
    a writer that picks its format from the suffix must be told it (``savefig(...,
    format="png")``)."""
    directory = path.parent
    tmp = _new_temporary(path)
    try:
        yield tmp
        if durable:
            with tmp.open("rb+") as f:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    if durable:
        fsync_directory(directory)


def write_atomic(path: Path, data: str | bytes, *, durable: bool = False) -> None:
    """Replace ``path`` by ``data`` (str as UTF-8) as :func:`replacing` says."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    with replacing(path, durable=durable) as tmp:
        tmp.write_bytes(raw)


def _new_temporary(path: Path) -> Path:
    """A new empty file ``.NAME.XXXXXXXX.tmp`` beside ``path``, created with the permissions
    a new file gets there (the umask's), not a temporary file's 0600."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    while True:
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
        try:
            os.close(os.open(tmp, flags, 0o666))
        except FileExistsError:
            continue
        return tmp


def fsync_directory(directory: Path) -> None:
    """Make a rename in ``directory`` survive a power loss (where the file system allows
    opening a folder; elsewhere nothing)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
