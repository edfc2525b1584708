"""The live scope's ring: samples from the bridge's loop to the scope's server process through
shared memory (docs/scope.md "The loop never waits for it").

One writer (the loop, :class:`RingWriter`) and one reader (the server process,
:class:`RingReader`) share an anonymous memory file (``os.memfd_create``; elsewhere an unlinked
temporary file) that the reader gets as an inherited file descriptor. Nothing has a name on a
file system, so nothing is left behind when either process is killed.

The layout (little-endian)::

    header  64 B   magic u32 | capacity u32 | write_seq u64 | dropped u64 | closed u32 |
                   meta_gen u32 | message_gen u32
    meta    8 KiB  length u32 | JSON (the page's /meta)
    message 1 KiB  length u32 | UTF-8 (the controller's stop message)
    slots   capacity x 72 B: seq i64 | 7 x f64 | state i32 | stop i32 (:data:`COLUMNS`)

The writer's per-cycle work is a ``struct.pack_into`` of the sample into slot
``seq % capacity``, then one 8-byte store of ``write_seq`` (the publication). No lock, no system
call, nothing that waits for the reader. The reader takes the slots after the last ``seq`` it
saw, then reads ``write_seq`` again and keeps only the slots the writer cannot have
overwritten meanwhile (and whose stored ``seq`` is the one expected); everything else is
counted as dropped. The rare blobs (meta, stop message) are written under a sequence lock
(generation odd while writing). On x86 stores are seen in program order (TSO), so a published
``write_seq`` implies its slot.

The header's words are read and written through ``memoryview.cast`` views, one aligned load
or store each, never by ``struct.pack_into``: that zero-fills its bytes before it writes them,
so a reader could read ``write_seq`` as 0 in the middle of a publication; as the check's
second read, 0 lets every slot pass, one being overwritten included (a torn sample: seen once
in 2,351 under load before this).
"""

from __future__ import annotations

import mmap
import os
import struct
import tempfile
from typing import Any

MAGIC = 0x53434F50  # "SCOP"
#: The columns of a sample, in order (SI; positions in load units).
COLUMNS = (
    "seq",
    "t_s",
    "following_error",
    "beta_rad_s",
    "lambda",
    "motor_speed_rad_s",
    "load_position",
    "torque_nm",
    "state",
    "stop",
)
Sample = tuple[int, float, float, float, float, float, float, float, int, int]

SLOT = struct.Struct("<q7d2i")
SLOT_BYTES = SLOT.size
HEADER = struct.Struct("<IIQQIII")
_U32 = struct.Struct("<I")
OFF_WRITE_SEQ = 8
OFF_DROPPED = 16
OFF_CLOSED = 24
OFF_META_GEN = 28
OFF_MESSAGE_GEN = 32
HEADER_BYTES = 64
META_OFFSET = HEADER_BYTES
META_BYTES = 8192
MESSAGE_OFFSET = META_OFFSET + META_BYTES
MESSAGE_BYTES = 1024
SLOTS_OFFSET = MESSAGE_OFFSET + MESSAGE_BYTES
#: The header's words as indices of its 8-byte and 4-byte views (:class:`_Words`).
W_WRITE_SEQ, W_DROPPED = OFF_WRITE_SEQ // 8, OFF_DROPPED // 8
U_CLOSED, U_META_GEN, U_MESSAGE_GEN = OFF_CLOSED // 4, OFF_META_GEN // 4, OFF_MESSAGE_GEN // 4
#: Retries of a blob read that met the writer mid-write before it keeps what it had.
BLOB_RETRIES = 1000


def ring_bytes(capacity: int) -> int:
    return SLOTS_OFFSET + capacity * SLOT.size


def _memory_file(size: int) -> int:
    """A file descriptor of ``size`` zeroed bytes with no name (inheritable by a child)."""
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("bridge-scope")  # close-on-exec: the server gets it by pass_fds
    else:  # pragma: no cover - not Linux
        with tempfile.TemporaryFile() as f:
            fd = os.dup(f.fileno())
    os.ftruncate(fd, size)
    return fd


class _Words:
    """The mapping's 8-byte and 4-byte words (native order: little-endian on the platforms
    this runs on, as the layout; an item access is one aligned load or store)."""

    def __init__(self, buf: mmap.mmap) -> None:
        self.u64 = memoryview(buf).cast("Q")
        self.u32 = memoryview(buf).cast("I")

    def release(self) -> None:
        self.u64.release()
        self.u32.release()


class RingWriter:
    """The loop's end: :meth:`push` one sample per cycle. ``capacity``: a power of two."""

    def __init__(self, capacity: int) -> None:
        if capacity < 2 or capacity & (capacity - 1):
            raise ValueError(f"ring capacity {capacity}: a power of two >= 2")
        self.capacity = capacity
        self.fd = _memory_file(ring_bytes(capacity))
        self.buf = mmap.mmap(self.fd, ring_bytes(capacity))
        HEADER.pack_into(self.buf, 0, MAGIC, capacity, 0, 0, 0, 0, 0)
        self.words = _Words(self.buf)
        self.seq = 0
        self._mask = capacity - 1
        self._pack = SLOT.pack_into
        self._u64 = self.words.u64

    def push(
        self,
        t_s: float,
        following_error: float,
        beta_rad_s: float,
        lam: float,
        motor_speed_rad_s: float,
        load_position: float,
        torque_nm: float,
        state: int,
        stop: int,
    ) -> None:
        """One sample into the next slot, then published. Never waits."""
        seq = self.seq + 1
        self.seq = seq
        buf = self.buf
        self._pack(
            buf,
            SLOTS_OFFSET + (seq & self._mask) * SLOT_BYTES,
            seq,
            t_s,
            following_error,
            beta_rad_s,
            lam,
            motor_speed_rad_s,
            load_position,
            torque_nm,
            state,
            stop,
        )
        self._u64[W_WRITE_SEQ] = seq  # the publication: one store

    def set_meta(self, data: bytes) -> None:
        _write_blob(self.buf, self.words, U_META_GEN, META_OFFSET, META_BYTES, data)

    def set_message(self, text: str) -> None:
        _write_blob(
            self.buf,
            self.words,
            U_MESSAGE_GEN,
            MESSAGE_OFFSET,
            MESSAGE_BYTES,
            text.encode("utf-8", "replace"),
        )

    def mark_closed(self) -> None:
        self.words.u32[U_CLOSED] = 1

    @property
    def dropped(self) -> int:
        """Samples the reader counted as dropped (it writes the count back)."""
        return int(self.words.u64[W_DROPPED])

    def close(self) -> None:
        self.words.release()
        self.buf.close()
        os.close(self.fd)


def _write_blob(buf: Any, words: _Words, gen: int, off: int, size: int, data: bytes) -> None:
    data = data[: size - 4]
    g = words.u32[gen]
    words.u32[gen] = g + 1  # odd: being written
    _U32.pack_into(buf, off, len(data))
    buf[off + 4 : off + 4 + len(data)] = data
    words.u32[gen] = g + 2


class RingReader:
    """The server's end over the mapping of a writer's file descriptor ``fd``."""

    def __init__(self, fd: int) -> None:
        size = os.fstat(fd).st_size
        self.buf = mmap.mmap(fd, size)
        magic, self.capacity = HEADER.unpack_from(self.buf, 0)[:2]
        if magic != MAGIC or ring_bytes(self.capacity) != size:
            raise ValueError(f"fd {fd}: not a scope ring")
        self.words = _Words(self.buf)
        self.last = 0  # the last seq taken
        self.dropped = 0
        self._blobs: dict[int, bytes] = {}

    @property
    def write_seq(self) -> int:
        return int(self.words.u64[W_WRITE_SEQ])

    @property
    def closed(self) -> bool:
        return bool(self.words.u32[U_CLOSED])

    def take(self) -> list[Sample]:
        """The samples published since the last take, oldest first; those the writer has
        overwritten (or may have been overwriting while read) are counted in ``dropped``."""
        head = self.write_seq
        if head <= self.last:
            return []
        cap = self.capacity
        first = max(self.last + 1, head - cap + 1)
        rows = [
            SLOT.unpack_from(self.buf, SLOTS_OFFSET + (s % cap) * SLOT_BYTES)
            for s in range(first, head + 1)
        ]
        # a slot of seq s is rewritten when seq s + cap is being written: after the copy,
        # only slots above write_seq + 1 - cap are sure to be the ones read
        safe = max(first, self.write_seq - cap + 2)
        kept: list[Sample] = [
            r for i, r in enumerate(rows) if first + i >= safe and r[0] == first + i
        ]
        self.dropped += (head - self.last) - len(kept)
        self.last = head
        self.words.u64[W_DROPPED] = self.dropped
        return kept

    def meta(self) -> bytes:
        return self._blob(U_META_GEN, META_OFFSET)

    def message(self) -> str:
        return self._blob(U_MESSAGE_GEN, MESSAGE_OFFSET).decode("utf-8", "replace")

    def _blob(self, gen_index: int, off: int) -> bytes:
        for _ in range(BLOB_RETRIES):
            gen = self.words.u32[gen_index]
            if gen & 1:
                continue
            n = _U32.unpack_from(self.buf, off)[0]
            data = bytes(self.buf[off + 4 : off + 4 + n])
            if self.words.u32[gen_index] == gen:
                self._blobs[gen_index] = data
                return data
        return self._blobs.get(gen_index, b"")

    def close(self) -> None:
        self.words.release()
        self.buf.close()
