"""A CiA 301 SDO server for a canopen ``LocalNode``: the checks come before the application.

canopen's :class:`canopen.sdo.SdoServer` hands a write to the node with whatever length the
client sent (a BOOLEAN takes four bytes, an empty write ends in an IndexError and 0800 0000),
serves a plain variable at any sub-index, makes up array members the EDS does not declare,
answers a block upload with a plain upload and lets a short frame raise ``struct.error``.
:class:`CheckedSdoServer` replaces its ``on_request`` and answers every request as CiA 301
(v4.2, 7.2.4) says, in this order of checks:

1. frame: 8 data bytes, else ignored (the node's frame guard counts it before);
2. protocol: a known client command specifier in a fitting transfer state, else 0504 0001;
   toggle bit alternated (0503 0000); block size 1..127 (0504 0002);
3. object: the index exists (0602 0000); the sub-index is declared in the EDS -- sub-index 0
   only for a plain variable (0609 0011);
4. access: read of a write-only object 0601 0001, write of a ro/const object 0601 0002;
5. length of a fixed-size data type: more bytes 0607 0012, fewer 0607 0013; a segmented
   download whose data differ from the size it announced 0607 0010;
6. value against the EDS: BOOLEAN other than 0/1 0609 0030, LowLimit/HighLimit 0609 0032 /
   0609 0031 (integers, and REAL32/REAL64 with :func:`apply_real_limits`; NaN 0609 0030 where
   a limit is declared);
7. the application (the node's write callbacks): any code it raises as
   ``canopen.SdoAbortedError`` (value rules, 0800 0022 device state, ...).

Refused writes change nothing: the node's write callbacks and store run only after 1-6 pass,
and a callback that raises stores nothing. Transfers: expedited and segmented upload and
download, block upload (7.2.4.3.9-7.2.4.3.13, with CRC when the client asks for it, protocol
switch to a normal upload when the data fit the client's threshold); block download is
answered with 0504 0001 (the client then uses a segmented download).
"""

from __future__ import annotations

import configparser
import logging
import math
import re
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

import canopen
from canopen import objectdictionary as cod
from canopen.objectdictionary.datatypes import BOOLEAN, FLOAT_TYPES, INTEGER_TYPES
from canopen.sdo import SdoAbortedError, SdoServer

from virtual_bus.contract import SDO_LENGTH, SdoAbort, sdo_rx_cob_id, sdo_tx_cob_id, type_size

logger = logging.getLogger(__name__)

_HEADER = struct.Struct("<BHB")
_U32 = struct.Struct("<I")
_MAX_BLOCK = 127

# client command specifiers (bits 7..5 of byte 0)
_CCS_SEGMENT_DOWNLOAD, _CCS_DOWNLOAD, _CCS_UPLOAD, _CCS_SEGMENT_UPLOAD = 0, 1, 2, 3
_CCS_ABORT, _CCS_BLOCK_UPLOAD, _CCS_BLOCK_DOWNLOAD = 4, 5, 6
# block upload client sub-commands (bits 1..0)
_CS_INITIATE, _CS_END, _CS_ACK, _CS_START = 0, 1, 2, 3


def crc16_ccitt(data: bytes, crc: int = 0) -> int:
    """CRC of the SDO block transfer (CiA 301 7.2.4.3.16: x^16 + x^12 + x^5 + 1, start 0)."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


class _Phase(Enum):
    IDLE = "idle"
    DOWNLOAD = "segmented download"
    UPLOAD = "segmented upload"
    BLOCK_INIT = "block upload initiated"
    BLOCK_SENT = "block upload: block sent"
    BLOCK_END = "block upload: end sent"


@dataclass
class _Transfer:
    phase: _Phase = _Phase.IDLE
    index: int = 0
    subindex: int = 0
    toggle: int = 0
    size: int | None = None  # announced size of a segmented download
    data: bytearray = field(default_factory=bytearray)
    position: int = 0  # block upload: bytes acknowledged
    block_size: int = _MAX_BLOCK
    last_block_bytes: int = 0


class CheckedSdoServer(SdoServer):
    """SDO server of ``node`` on 0x600/0x580 + node-ID (see the module docstring)."""

    def __init__(self, node: canopen.LocalNode, blocked: Callable[[], bool] | None = None) -> None:
        super().__init__(sdo_rx_cob_id(node.id), sdo_tx_cob_id(node.id), node)
        self._local = node
        #: while it returns True no request is answered (NMT Stopped, CiA 301 table 46)
        self._blocked = blocked
        self._transfer = _Transfer()
        #: Requests answered with an abort, and the last code sent (diagnostics).
        self.aborts_sent = 0
        self.last_abort: int | None = None

    # --- entry point ---------------------------------------------------------------------------
    def on_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if len(data) != SDO_LENGTH:
            logger.debug("SDO request with %d bytes ignored (needs 8)", len(data))
            return
        if self._blocked is not None and self._blocked():
            return
        command = data[0]
        ccs = command >> 5
        t = self._transfer
        try:
            if ccs == _CCS_DOWNLOAD:
                self._init_download(command, bytes(data))
            elif ccs == _CCS_SEGMENT_DOWNLOAD:
                self._segment_download(command, bytes(data))
            elif ccs == _CCS_UPLOAD:
                self._init_upload(bytes(data))
            elif ccs == _CCS_SEGMENT_UPLOAD:
                self._segment_upload(command)
            elif ccs == _CCS_BLOCK_UPLOAD:
                self._block_upload(command, bytes(data))
            elif ccs == _CCS_ABORT:
                self._transfer = _Transfer()  # the client ended the transfer; no answer
            else:  # block download (6) and the reserved 7
                if ccs == _CCS_BLOCK_DOWNLOAD:
                    _, t.index, t.subindex = _HEADER.unpack_from(data)
                raise SdoAbortedError(SdoAbort.COMMAND_SPECIFIER)
        except SdoAbortedError as exc:
            self._send_abort(int(exc.code))
        except Exception:  # an application bug must not kill the bus thread
            logger.exception("SDO request %s failed in the application", bytes(data).hex())
            self._send_abort(SdoAbort.GENERAL)

    def _send_abort(self, code: int) -> None:
        t = self._transfer
        self.aborts_sent += 1
        self.last_abort = code
        self.send_response(struct.pack("<BHBI", 0x80, t.index, t.subindex, code))
        self._transfer = _Transfer()

    # --- object resolution ---------------------------------------------------------------------
    def _variable(self, index: int, subindex: int) -> cod.ODVariable:
        od = self._local.object_dictionary
        if index not in od:
            raise SdoAbortedError(SdoAbort.NO_OBJECT)
        obj = od[index]
        if isinstance(obj, cod.ODVariable):
            if subindex != 0:
                raise SdoAbortedError(SdoAbort.NO_SUBINDEX)
            return obj
        if subindex not in obj.subindices:  # ODArray makes up undeclared members
            raise SdoAbortedError(SdoAbort.NO_SUBINDEX)
        return obj.subindices[subindex]

    def _begin(self, index: int, subindex: int, phase: _Phase) -> _Transfer:
        self._transfer = _Transfer(phase=phase, index=index, subindex=subindex)
        return self._transfer

    # --- download --------------------------------------------------------------------------------
    def _init_download(self, command: int, request: bytes) -> None:
        _, index, subindex = _HEADER.unpack_from(request)
        t = self._begin(index, subindex, _Phase.IDLE)
        var = self._variable(index, subindex)
        if not var.writable:
            raise SdoAbortedError(SdoAbort.READ_ONLY)
        expedited, size_given = command & 0x02, command & 0x01
        if expedited:
            # size not indicated: the object's own size (at most the 4 data bytes)
            size = 4 - ((command >> 2) & 0x3) if size_given else min(4, _size_or(var, 4))
            self._write(var, request[4 : 4 + size])
        else:
            if size_given:
                t.size = _U32.unpack_from(request, 4)[0]
                _check_length(var, t.size)
            t.phase = _Phase.DOWNLOAD
        self.send_response(_HEADER.pack(0x60, index, subindex) + bytes(4))

    def _segment_download(self, command: int, request: bytes) -> None:
        t = self._transfer
        if t.phase is not _Phase.DOWNLOAD:
            raise SdoAbortedError(SdoAbort.COMMAND_SPECIFIER)
        if command & 0x10 != t.toggle:
            raise SdoAbortedError(SdoAbort.TOGGLE_BIT)
        unused = (command >> 1) & 0x7
        t.data += request[1 : 8 - unused]
        if t.size is not None and len(t.data) > t.size:
            raise SdoAbortedError(SdoAbort.LENGTH_MISMATCH)
        response = bytes([0x20 | t.toggle]) + bytes(7)
        if command & 0x01:  # last segment
            if t.size is not None and len(t.data) != t.size:
                raise SdoAbortedError(SdoAbort.LENGTH_MISMATCH)
            self._write(self._variable(t.index, t.subindex), bytes(t.data))
            self._transfer = _Transfer(index=t.index, subindex=t.subindex)
        else:
            t.toggle ^= 0x10
        self.send_response(response)

    def _write(self, var: cod.ODVariable, data: bytes) -> None:
        """Steps 5-7 of the module docstring, then the node stores the value."""
        _check_length(var, len(data))
        _check_value(var, data)
        self._local.set_data(var.index, var.subindex, data, check_writable=True)

    # --- upload ----------------------------------------------------------------------------------
    def _read(self, index: int, subindex: int) -> bytes:
        var = self._variable(index, subindex)
        if not var.readable:
            raise SdoAbortedError(SdoAbort.WRITE_ONLY)
        data = bytes(self._local.get_data(index, subindex, check_readable=True))
        if not data:
            raise SdoAbortedError(SdoAbort.NO_DATA)
        return data

    def _init_upload(self, request: bytes) -> None:
        _, index, subindex = _HEADER.unpack_from(request)
        t = self._begin(index, subindex, _Phase.IDLE)
        data = self._read(index, subindex)
        if len(data) <= 4:
            command = 0x43 | ((4 - len(data)) << 2)
            self.send_response(_HEADER.pack(command, index, subindex) + data.ljust(4, b"\0"))
            return
        t.phase, t.data = _Phase.UPLOAD, bytearray(data)
        self.send_response(_HEADER.pack(0x41, index, subindex) + _U32.pack(len(data)))

    def _segment_upload(self, command: int) -> None:
        t = self._transfer
        if t.phase is not _Phase.UPLOAD:
            raise SdoAbortedError(SdoAbort.COMMAND_SPECIFIER)
        if command & 0x10 != t.toggle:
            raise SdoAbortedError(SdoAbort.TOGGLE_BIT)
        chunk = bytes(t.data[t.position : t.position + 7])
        t.position += len(chunk)
        last = t.position >= len(t.data)
        response = bytes([t.toggle | ((7 - len(chunk)) << 1) | last]) + chunk.ljust(7, b"\0")
        if last:
            self._transfer = _Transfer(index=t.index, subindex=t.subindex)
        else:
            t.toggle ^= 0x10
        self.send_response(response)

    # --- block upload (CiA 301 7.2.4.3.9-13) -----------------------------------------------------
    def _block_upload(self, command: int, request: bytes) -> None:
        cs = command & 0x03
        t = self._transfer
        if cs == _CS_INITIATE:
            _, index, subindex = _HEADER.unpack_from(request)
            t = self._begin(index, subindex, _Phase.IDLE)
            block_size, threshold = request[4], request[5]
            if not 1 <= block_size <= _MAX_BLOCK:
                raise SdoAbortedError(SdoAbort.BLOCK_SIZE)
            data = self._read(index, subindex)
            if threshold and len(data) <= threshold:  # protocol switch (7.2.4.3.9)
                self._init_upload(request)
                return
            t.phase, t.data, t.block_size = _Phase.BLOCK_INIT, bytearray(data), block_size
            self.send_response(_HEADER.pack(0xC6, index, subindex) + _U32.pack(len(data)))
        elif cs == _CS_START and t.phase is _Phase.BLOCK_INIT:
            self._send_block()
        elif cs == _CS_ACK and t.phase is _Phase.BLOCK_SENT:
            acked, block_size = request[1], request[2]
            if not 1 <= block_size <= _MAX_BLOCK:
                raise SdoAbortedError(SdoAbort.BLOCK_SIZE)
            if acked > t.last_block_bytes // 7 + bool(t.last_block_bytes % 7):
                raise SdoAbortedError(SdoAbort.SEQUENCE_NUMBER)
            t.position = min(len(t.data), t.position + 7 * acked)
            t.block_size = block_size
            if t.position >= len(t.data):
                unused = (7 - len(t.data) % 7) % 7
                # sc = 1: this server supports CRC; the CRC is sent even when the client's
                # cc = 0 (it then ignores the field) -- canopen's client checks it whenever sc = 1
                crc = crc16_ccitt(bytes(t.data))
                t.phase = _Phase.BLOCK_END
                self.send_response(struct.pack("<BH", 0xC1 | (unused << 2), crc) + bytes(5))
            else:
                self._send_block()  # the next block, or the unacknowledged rest again
        elif cs == _CS_END and t.phase is _Phase.BLOCK_END:
            self._transfer = _Transfer(index=t.index, subindex=t.subindex)
        else:
            raise SdoAbortedError(SdoAbort.COMMAND_SPECIFIER)

    def _send_block(self) -> None:
        t = self._transfer
        rest = t.data[t.position : t.position + 7 * t.block_size]
        t.last_block_bytes = len(rest)
        t.phase = _Phase.BLOCK_SENT
        end = t.position + len(rest) >= len(t.data)
        segments = [rest[i : i + 7] for i in range(0, len(rest), 7)]
        for seq, chunk in enumerate(segments, start=1):
            last = end and seq == len(segments)
            self.send_response(bytes([seq | (0x80 if last else 0)]) + bytes(chunk).ljust(7, b"\0"))


# --- checks against the EDS (steps 5 and 6) ----------------------------------------------
def _size_or(var: cod.ODVariable, default: int) -> int:
    size = type_size(var.data_type) if var.data_type is not None else None
    return default if size is None else size


def _check_length(var: cod.ODVariable, length: int) -> None:
    size = type_size(var.data_type) if var.data_type is not None else None
    if size is None:
        return
    if length > size:
        raise SdoAbortedError(SdoAbort.LENGTH_TOO_HIGH)
    if length < size:
        raise SdoAbortedError(SdoAbort.LENGTH_TOO_LOW)


def _check_value(var: cod.ODVariable, data: bytes) -> None:
    if var.data_type == BOOLEAN:
        if data[0] not in (0, 1):
            raise SdoAbortedError(SdoAbort.VALUE_RANGE)
        return
    if var.data_type in FLOAT_TYPES:
        value = var.decode_raw(data)
        if math.isnan(value):  # no range holds NaN; a REAL32 object without limits takes it
            if var.min is not None or var.max is not None:
                raise SdoAbortedError(SdoAbort.VALUE_RANGE)
            return
    elif var.data_type not in INTEGER_TYPES:
        return
    else:
        value = var.decode_raw(data)
    if var.min is not None and value < var.min:
        raise SdoAbortedError(SdoAbort.TOO_LOW)
    if var.max is not None and value > var.max:
        raise SdoAbortedError(SdoAbort.TOO_HIGH)


_SECTION = re.compile(r"([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]{1,2}))?")


def apply_real_limits(od: canopen.ObjectDictionary, eds_path: str) -> None:
    """Give REAL32/REAL64 variables of ``od`` the LowLimit/HighLimit of their EDS.

    python canopen (2.4) reads LowLimit/HighLimit with ``int(text, 0)`` for every data type, so
    a REAL32 limit written as a decimal number (CiA 306) is silently dropped; the server would
    then take any value. This reads them as floats (configparser, the EDS's own text)."""
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read(eds_path, encoding="utf-8")
    for section in parser.sections():
        m = _SECTION.fullmatch(section)
        if not m:
            continue
        index, sub = int(m.group(1), 16), int(m.group(2) or "0", 16)
        if index not in od:
            continue
        obj = od[index]
        var = obj if isinstance(obj, cod.ODVariable) else obj.subindices.get(sub)
        if var is None or var.data_type not in FLOAT_TYPES:
            continue
        for key, attr in (("LowLimit", "min"), ("HighLimit", "max")):
            text = parser[section].get(key, "").strip()
            if text:
                setattr(var, attr, float(text))
