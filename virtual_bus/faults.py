"""Seeded fault injection around any python-can bus, for tests.

:class:`FaultInjectingBus` wraps an inner ``can.BusABC``. Frames pass a fault *stage* on the
receive path, the send path or both (:class:`Direction`). Per frame the stage draws exactly
``len(FaultKind)`` uniforms from its decision generator, in ``FaultKind`` order, whether or
not a kind is enabled (so enabling one fault never reshuffles which frames get another), and
applies, in this order:

* BURST: ``burst_length`` high-priority frames (ids uniform in ``burst_ids``) are put ahead
  of the frame (they are extra traffic, never faulted themselves);
* DROP: the frame is discarded (nothing else happens to it);
* WRONG_LENGTH: the DLC changes to another valid length; data truncated or padded;
* DUPLICATE: the frame is emitted twice;
* DELAY: the frame (and its duplicate) is held until ``clock() + delay_s``;
* REORDER: the frame (not if delayed) is held back and emitted right after the next frame
  that leaves the stage; while one frame is held, further REORDER draws are not applied.

Decision generators: ``random.Random(seed)`` for the receive stage, ``random.Random(seed + 1)``
for the send stage; new lengths, padding bytes and burst frames come from separate generators,
so the decisions are reproducible from the seed alone. Time comes from an injected ``clock``
(default ``time.monotonic``); with a fake clock call ``recv(timeout=0)`` or
:meth:`FaultInjectingBus.release_due` after advancing it.
"""

from __future__ import annotations

import copy
import heapq
import itertools
import math
import random
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from types import MappingProxyType

import can

from virtual_bus.errors import BusConfigError, FaultConfigError


class Direction(Enum):
    """Where faults are applied."""

    RECEIVE = "receive"
    SEND = "send"
    BOTH = "both"


class FaultKind(Enum):
    """Injected fault kinds, in decision-draw order."""

    BURST = "burst"
    DROP = "drop"
    WRONG_LENGTH = "wrong_length"
    DUPLICATE = "duplicate"
    DELAY = "delay"
    REORDER = "reorder"


_CAN_LENGTHS = tuple(range(9))
#: Frames taken from the inner bus per receive call at most.
_MAX_DRAIN = 256
_CAN_FD_LENGTHS = (*range(9), 12, 16, 20, 24, 32, 48, 64)


def _check_probability(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
        raise FaultConfigError(f"{name} must be a probability in [0, 1], got {value!r}")


@dataclass(frozen=True)
class FaultConfig:
    """Fault probabilities per frame (each in [0, 1]) and their parameters.

    seed: int >= 0 for the decision generators. direction: where faults apply.
    delay_s: hold time of a delayed frame in seconds of the injected clock (>= 0, finite).
    burst_ids: inclusive (low, high) standard CAN-id range of burst frames, 0..0x7FF
    (default 0x001..0x07F: higher priority than every CANopen service except NMT).
    burst_length: frames per burst, 1..1000. burst_dlc: data length of burst frames, 0..8.
    """

    seed: int = 0
    direction: Direction = Direction.RECEIVE
    drop_p: float = 0.0
    wrong_length_p: float = 0.0
    duplicate_p: float = 0.0
    delay_p: float = 0.0
    delay_s: float = 0.0
    reorder_p: float = 0.0
    burst_p: float = 0.0
    burst_ids: tuple[int, int] = (0x001, 0x07F)
    burst_length: int = 4
    burst_dlc: int = 8

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise FaultConfigError(f"seed must be an int >= 0, got {self.seed!r}")
        if not isinstance(self.direction, Direction):
            raise FaultConfigError(
                f"direction must be a Direction ({[d.name for d in Direction]}), "
                f"got {self.direction!r}"
            )
        for kind in FaultKind:
            _check_probability(f"{kind.value}_p", self.probability(kind))
        if not isinstance(self.delay_s, int | float) or not (
            math.isfinite(self.delay_s) and self.delay_s >= 0.0
        ):
            raise FaultConfigError(f"delay_s must be finite and >= 0 s, got {self.delay_s!r}")
        low, high = self._burst_range()
        if not 0 <= low <= high <= 0x7FF:
            raise FaultConfigError(
                f"burst_ids must be (low, high) with 0 <= low <= high <= 0x7FF, "
                f"got {self.burst_ids!r}"
            )
        if not isinstance(self.burst_length, int) or not 1 <= self.burst_length <= 1000:
            raise FaultConfigError(f"burst_length must be 1..1000, got {self.burst_length!r}")
        if not isinstance(self.burst_dlc, int) or not 0 <= self.burst_dlc <= 8:
            raise FaultConfigError(f"burst_dlc must be 0..8, got {self.burst_dlc!r}")

    def _burst_range(self) -> tuple[int, int]:
        try:
            low, high = self.burst_ids
        except (TypeError, ValueError):
            raise FaultConfigError(
                f"burst_ids must be a (low, high) pair of ints, got {self.burst_ids!r}"
            ) from None
        if not isinstance(low, int) or not isinstance(high, int):
            raise FaultConfigError(f"burst_ids must hold ints, got {self.burst_ids!r}")
        return low, high

    def probability(self, kind: FaultKind) -> float:
        """The per-frame probability of ``kind``."""
        return {
            FaultKind.BURST: self.burst_p,
            FaultKind.DROP: self.drop_p,
            FaultKind.WRONG_LENGTH: self.wrong_length_p,
            FaultKind.DUPLICATE: self.duplicate_p,
            FaultKind.DELAY: self.delay_p,
            FaultKind.REORDER: self.reorder_p,
        }[kind]


def decision_rng(seed: int, direction: Direction) -> random.Random:
    """The decision generator of the RECEIVE or SEND stage (documented contract)."""
    if direction is Direction.BOTH:
        raise BusConfigError("a stage is RECEIVE or SEND, not BOTH")
    return random.Random(seed if direction is Direction.RECEIVE else seed + 1)


@dataclass(frozen=True)
class FaultCounters:
    """Snapshot of what a :class:`FaultInjectingBus` did.

    faults[(direction, kind, can_id)]: injected faults (for BURST the id of the burst frame);
    frames_in/frames_out[direction]: frames entering/leaving the stage; pending[direction]:
    frames held (delay line, reorder slot, not yet received). Directions are RECEIVE and SEND.
    Conservation per direction: in + duplicates + bursts == out + drops + pending.
    """

    faults: Mapping[tuple[Direction, FaultKind, int], int]
    frames_in: Mapping[Direction, int]
    frames_out: Mapping[Direction, int]
    pending: Mapping[Direction, int]

    def count(
        self,
        kind: FaultKind | None = None,
        *,
        direction: Direction | None = None,
        can_id: int | None = None,
    ) -> int:
        """Total faults matching the given kind/direction/id (``None`` = any)."""
        return sum(
            n
            for (d, k, i), n in self.faults.items()
            if (kind is None or k is kind)
            and (direction is None or d is direction)
            and (can_id is None or i == can_id)
        )

    def by_id(self, kind: FaultKind, direction: Direction | None = None) -> dict[int, int]:
        """Faults of ``kind`` per CAN id."""
        out: Counter[int] = Counter()
        for (d, k, i), n in self.faults.items():
            if k is kind and (direction is None or d is direction):
                out[i] += n
        return dict(out)


@dataclass
class _Stage:
    """The fault pipeline of one direction. Not thread-safe; the bus holds the lock."""

    direction: Direction
    config: FaultConfig
    rng: random.Random
    payload_rng: random.Random
    ready: deque[can.Message] = field(default_factory=deque)
    delayed: list[tuple[float, int, can.Message]] = field(default_factory=list)
    swap: list[can.Message] | None = None
    faults: Counter[tuple[Direction, FaultKind, int]] = field(default_factory=Counter)
    frames_in: int = 0
    frames_out: int = 0
    _seq: itertools.count[int] = field(default_factory=itertools.count)

    def _count(self, kind: FaultKind, can_id: int) -> None:
        self.faults[(self.direction, kind, can_id)] += 1

    def process(self, msg: can.Message, now: float) -> None:
        """Run one frame through the stage (outputs go to ``ready`` / ``delayed``)."""
        self.frames_in += 1
        if msg.is_error_frame:
            self.ready.append(msg)
            return
        cfg = self.config
        u = {kind: self.rng.random() for kind in FaultKind}
        if u[FaultKind.BURST] < cfg.burst_p:
            for burst in self._burst(msg):
                self._count(FaultKind.BURST, burst.arbitration_id)
                self.ready.append(burst)
        if u[FaultKind.DROP] < cfg.drop_p:
            self._count(FaultKind.DROP, msg.arbitration_id)
            return
        if u[FaultKind.WRONG_LENGTH] < cfg.wrong_length_p:
            msg = self._wrong_length(msg)
            self._count(FaultKind.WRONG_LENGTH, msg.arbitration_id)
        out = [msg]
        if u[FaultKind.DUPLICATE] < cfg.duplicate_p:
            out.append(copy.copy(msg))
            self._count(FaultKind.DUPLICATE, msg.arbitration_id)
        if u[FaultKind.DELAY] < cfg.delay_p:
            self._count(FaultKind.DELAY, msg.arbitration_id)
            for m in out:
                heapq.heappush(self.delayed, (now + cfg.delay_s, next(self._seq), m))
        elif u[FaultKind.REORDER] < cfg.reorder_p and self.swap is None:
            self._count(FaultKind.REORDER, msg.arbitration_id)
            self.swap = out
            return
        else:
            self.ready.extend(out)
        if self.swap is not None:  # the frame held for reordering follows this one
            self.ready.extend(self.swap)
            self.swap = None

    def release_due(self, now: float) -> None:
        """Move delayed frames whose release time has come to ``ready``."""
        while self.delayed and self.delayed[0][0] <= now:
            self.ready.append(heapq.heappop(self.delayed)[2])

    def next_release(self) -> float | None:
        return self.delayed[0][0] if self.delayed else None

    def pop_ready(self) -> can.Message | None:
        if not self.ready:
            return None
        self.frames_out += 1
        return self.ready.popleft()

    def pending(self) -> int:
        return len(self.ready) + len(self.delayed) + (len(self.swap) if self.swap else 0)

    def _wrong_length(self, msg: can.Message) -> can.Message:
        lengths = _CAN_FD_LENGTHS if msg.is_fd else _CAN_LENGTHS
        new_len = self.payload_rng.choice([n for n in lengths if n != msg.dlc])
        if msg.is_remote_frame:
            data = b""
        else:
            pad = new_len - len(msg.data)
            data = bytes(msg.data[:new_len]) + self.payload_rng.randbytes(max(pad, 0))
        return can.Message(
            timestamp=msg.timestamp,
            arbitration_id=msg.arbitration_id,
            is_extended_id=msg.is_extended_id,
            is_remote_frame=msg.is_remote_frame,
            channel=msg.channel,
            dlc=new_len,
            data=data,
            is_fd=msg.is_fd,
            is_rx=msg.is_rx,
            bitrate_switch=msg.bitrate_switch,
            error_state_indicator=msg.error_state_indicator,
        )

    def _burst(self, trigger: can.Message) -> list[can.Message]:
        low, high = self.config.burst_ids
        return [
            can.Message(
                timestamp=trigger.timestamp,
                arbitration_id=self.payload_rng.randint(low, high),
                is_extended_id=False,
                channel=trigger.channel,
                data=self.payload_rng.randbytes(self.config.burst_dlc),
                is_rx=trigger.is_rx,
            )
            for _ in range(self.config.burst_length)
        ]


class FaultInjectingBus(can.BusABC):
    """A python-can bus that injects seeded faults into the frames of an ``inner`` bus.

    Overrides only the python-can hooks ``_recv_internal`` and ``send`` (so ``recv``,
    filters, iteration, ``send_periodic`` and ``can.Notifier`` work as for any bus) and owns
    ``inner``: :meth:`shutdown` shuts it down. Usable as the bus of ``canopen.Network(bus)``.
    """

    def __init__(
        self,
        inner: can.BusABC,
        config: FaultConfig,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not isinstance(inner, can.BusABC):
            raise BusConfigError(f"inner must be a can.BusABC, got {type(inner).__name__}")
        if not isinstance(config, FaultConfig):
            raise BusConfigError(f"config must be a FaultConfig, got {type(config).__name__}")
        self._inner = inner
        self.config = config
        self._clock = clock
        self._lock = threading.RLock()
        self._stages: dict[Direction, _Stage] = {}
        for direction in (Direction.RECEIVE, Direction.SEND):
            if config.direction in (direction, Direction.BOTH):
                self._stages[direction] = _Stage(
                    direction=direction,
                    config=config,
                    rng=decision_rng(config.seed, direction),
                    payload_rng=random.Random(f"payload:{direction.value}:{config.seed}"),
                )
        self.channel_info = f"fault-injecting {inner.channel_info}"
        self._can_protocol = inner.protocol
        super().__init__(channel=None)

    @property
    def inner(self) -> can.BusABC:
        """The wrapped bus."""
        return self._inner

    @property
    def counters(self) -> FaultCounters:
        """A consistent snapshot of the fault counters."""
        with self._lock:
            faults: Counter[tuple[Direction, FaultKind, int]] = Counter()
            for stage in self._stages.values():
                faults.update(stage.faults)
            return FaultCounters(
                faults=MappingProxyType(dict(faults)),
                frames_in=MappingProxyType({d: s.frames_in for d, s in self._stages.items()}),
                frames_out=MappingProxyType({d: s.frames_out for d, s in self._stages.items()}),
                pending=MappingProxyType({d: s.pending() for d, s in self._stages.items()}),
            )

    def _check_open(self) -> None:
        if self._is_shutdown:
            raise can.CanOperationError("Cannot operate on a closed FaultInjectingBus")

    def release_due(self) -> None:
        """Release delayed frames whose time has come: sent frames go to the inner bus,
        received ones become available to ``recv``. Called by ``send`` and ``recv`` too."""
        self._check_open()
        with self._lock:
            now = self._clock()
            for stage in self._stages.values():
                stage.release_due(now)
            tx = self._stages.get(Direction.SEND)
            while tx is not None and (msg := tx.pop_ready()) is not None:
                self._inner.send(msg)

    def _wait_s(self, timeout: float | None) -> float | None:
        """``timeout`` shortened to the next release time of the delay lines."""
        releases = [t for s in self._stages.values() if (t := s.next_release()) is not None]
        if not releases:
            return timeout
        until_s = max(0.0, min(releases) - self._clock())
        return until_s if timeout is None else min(timeout, until_s)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self.release_due()
        rx = self._stages.get(Direction.RECEIVE)
        with self._lock:
            if rx is not None and (ready := rx.pop_ready()) is not None:
                return ready, False
            wait_s = self._wait_s(timeout)
        msg = self._inner.recv(wait_s)
        if rx is None:
            self.release_due()
            return msg, False
        with self._lock:
            # Every frame already waiting enters the stage now, so its delay starts when it
            # arrived (bounded, so a flooding inner bus cannot starve the caller).
            for _ in range(_MAX_DRAIN):
                if msg is None:
                    break
                rx.process(msg, self._clock())
                msg = self._inner.recv(0.0)
            if msg is not None:
                rx.process(msg, self._clock())
            rx.release_due(self._clock())
            return rx.pop_ready(), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_open()
        tx = self._stages.get(Direction.SEND)
        if tx is None:
            self._inner.send(msg, timeout)
            return
        with self._lock:
            now = self._clock()
            tx.process(msg, now)
            tx.release_due(now)
            while (out := tx.pop_ready()) is not None:
                self._inner.send(out, timeout)

    @property
    def state(self) -> can.BusState:
        """The inner bus's state."""
        return self._inner.state

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        self._inner.state = new_state

    def flush_tx_buffer(self) -> None:
        self._inner.flush_tx_buffer()

    def shutdown(self) -> None:
        """Stop periodic tasks, discard held frames and shut the inner bus down."""
        was_shut = self._is_shutdown
        super().shutdown()
        if not was_shut:
            self._inner.shutdown()
