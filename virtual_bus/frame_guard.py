"""The check every received CAN frame passes before a CANopen handler sees it.

A node (the bridge, the simulated drive) builds a :class:`FrameGuard` with a *classifier*:
``classify(cob_id, length) -> FrameFault | None`` knows which COB-IDs the node consumes, the
length each needs (CiA 301: NMT 2, heartbeat 1, SDO 8, EMCY 8, SYNC 0/1, PDOs their mapping)
and whether its NMT state allows the service (CiA 301 table 46). Before that the guard
itself refuses remote (RTR) frames, 29-bit identifiers and error frames -- an RTR only after
the node's optional ``remote(cob_id)`` has declined it (the drive answers an RTR for a TPDO
that allows one, CiA 301 1800h bit 30). A refused frame is counted by kind (the node shows
the counts in its object dictionary) and logged rate-limited (the 1st, 10th, 100th, ... of
each kind); it is never raised into the loop. ``check`` is cheap: a few comparisons and one
call per frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from enum import IntEnum

import can

logger = logging.getLogger(__name__)


class FrameFault(IntEnum):
    """Why a frame was refused; the value is the sub-index of the diagnostic record."""

    BAD_LENGTH = 1  # data length not the one the service at this COB-ID needs
    UNKNOWN_COB_ID = 2  # no service of this node consumes it (other nodes' traffic included)
    NOT_IN_STATE = 3  # the node's NMT state does not allow the service (CiA 301 table 46)
    SECOND_SYNC_PRODUCER = 4  # a SYNC this node did not send while it is the SYNC producer
    REMOTE = 5  # RTR frame (no remote-request service here)
    EXTENDED_ID = 6  # 29-bit identifier (CANopen uses 11-bit COB-IDs)
    ERROR_FRAME = 7  # error frame reported by the interface


Classifier = Callable[[int, int], "FrameFault | None"]


class FrameGuard:
    """Counts and drops frames no handler of the node may see (see the module docstring).

    name: the node in log lines. classify: see the module docstring.
    on_refused(fault, cob_id): optional reaction of the node (e.g. the bridge stops the axis on
    a second SYNC producer, counts a bad TPDO in 2107h too); it must not raise.
    remote(cob_id): optional; answers a remote frame the node serves and returns True (the
    frame counts as accepted and goes to no handler), else False (refused as REMOTE).
    """

    def __init__(
        self,
        name: str,
        classify: Classifier,
        on_refused: Callable[[FrameFault, int], None] | None = None,
        remote: Callable[[int], bool] | None = None,
    ) -> None:
        self.name = name
        self.classify = classify
        self.on_refused = on_refused
        self.remote = remote
        self.counts: dict[FrameFault, int] = dict.fromkeys(FrameFault, 0)
        self.accepted = 0

    def check(self, msg: can.Message) -> bool:
        """True: hand ``msg`` to the handlers; False: refused (counted, logged)."""
        if msg.is_error_frame:
            fault: FrameFault | None = FrameFault.ERROR_FRAME
        elif msg.is_remote_frame:
            remote = self.remote
            if remote is not None and not msg.is_extended_id and remote(msg.arbitration_id):
                self.accepted += 1
                return False  # answered by the node; no handler takes a remote frame
            fault = FrameFault.REMOTE
        elif msg.is_extended_id:
            fault = FrameFault.EXTENDED_ID
        else:
            fault = self.classify(msg.arbitration_id, len(msg.data))
        if fault is None:
            self.accepted += 1
            return True
        self.refuse(fault, msg.arbitration_id, len(msg.data))
        return False

    def admit(self, cob_id: int, length: int) -> bool:
        """:meth:`check` for a frame known only by COB-ID and length (a canopen callback)."""
        fault = self.classify(cob_id, length)
        if fault is None:
            self.accepted += 1
            return True
        self.refuse(fault, cob_id, length)
        return False

    def refuse(self, fault: FrameFault, cob_id: int, length: int) -> None:
        """Count and log a refused frame (also for checks the node makes later)."""
        n = self.counts[fault] + 1
        self.counts[fault] = n
        if _is_power_of_ten(n):
            logger.warning(
                "%s: frame 0x%03X with %d bytes refused: %s (%d so far)",
                self.name,
                cob_id,
                length,
                fault.name.lower().replace("_", " "),
                n,
            )
        if self.on_refused is not None:
            try:
                self.on_refused(fault, cob_id)
            except Exception:  # a reaction must never take the receive loop down
                logger.exception("%s: reaction to a refused frame failed", self.name)

    def count(self, fault: FrameFault) -> int:
        return self.counts[fault]

    @property
    def refused(self) -> int:
        return sum(self.counts.values())


def _is_power_of_ten(n: int) -> bool:
    while n % 10 == 0:
        n //= 10
    return n == 1
