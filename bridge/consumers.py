"""The nodes the bridge consumes heartbeats and EMCYs of, one row each (like 1016h's entries).

The bridge watches the drive and, when a CiA 406 encoder node supplies the load position,
that node too: the same three checks for each, in the same order (an EMCY with a non-zero
code, the heartbeat not within the 1016h consumer time, a heartbeat reporting a state other
than Operational). :class:`NodeWatch` is one row; :class:`~bridge.cycle.CycleController` keeps
a tuple of them and checks them in turn, so a third supervised node is one more row.

CiA 301 7.2.8.3.2.2: a consumer watches from the first heartbeat it receives. The drive's NMT
state is supervised from its first Operational heartbeat after the start-up
(:attr:`NodeWatch.states_from_operational`): a Pre-operational one the drive sent before it
took the NMT start, read late on a busy machine, is not a drive that left Operational.
"""

from __future__ import annotations

from dataclasses import dataclass

from virtual_bus.contract import NmtState

NMT_OPERATIONAL = int(NmtState.OPERATIONAL)
NMT_BOOTUP = int(NmtState.INITIALISING)


@dataclass(eq=False, slots=True)
class NodeWatch:
    """One supervised node: what was last heard of it, and how a stop for it reads.

    ``name``: the node as the stop message names it ("drive", "encoder node 5");
    ``emcy_consequence``: appended to an EMCY's stop message (why it stops the axis);
    ``emcy_reason`` / ``heartbeat_reason`` / ``state_reason``: the bridge's stop reasons
    (:class:`bridge.cycle.StopReason` values) of the three checks.
    """

    name: str
    emcy_reason: int
    heartbeat_reason: int
    state_reason: int
    emcy_consequence: str = ""
    states_from_operational: bool = False
    heartbeat_at: float | None = None
    state: int = NMT_OPERATIONAL
    operational_seen: bool = False
    emcy_pending: tuple[int, int] | None = None

    def forget(self) -> None:
        """Forget what was heard (the start-up's boot-up and pre-operational heartbeats,
        its EMCYs): the watch begins with the next heartbeat."""
        self.heartbeat_at = None
        self.state = NMT_OPERATIONAL
        self.operational_seen = False
        self.emcy_pending = None

    def on_heartbeat(self, nmt_state: int, now_s: float) -> None:
        """A heartbeat (the NMT state byte; its toggle bit ignored) at ``now_s``."""
        self.heartbeat_at = now_s
        state = nmt_state & 0x7F
        if state == NMT_OPERATIONAL:
            self.operational_seen = True
        if self.operational_seen or not self.states_from_operational:
            self.state = state

    def on_emcy(self, error_code: int, error_register: int) -> None:
        """An EMCY; code 0000h (error reset) leaves nothing pending."""
        if error_code != 0:
            self.emcy_pending = (error_code, error_register)

    def quiet(self, now_s: float, consumer_ms: int) -> bool:
        """Nothing to stop for at ``now_s`` (the loop's fast path; :meth:`check` says why
        not)."""
        if self.emcy_pending is not None:
            return False
        at = self.heartbeat_at
        if at is None:
            return True
        return self.state == NMT_OPERATIONAL and not (
            consumer_ms and now_s - at > consumer_ms / 1000.0
        )

    def check(self, now_s: float, consumer_ms: int) -> tuple[int, str] | None:
        """The stop this node calls for at ``now_s`` -- (stop reason, message) -- or None;
        a pending EMCY is consumed."""
        if self.emcy_pending is not None:
            code, register = self.emcy_pending
            self.emcy_pending = None
            return self.emcy_reason, (
                f"{self.name} EMCY error code 0x{code:04X}, error register 0x{register:02X}"
                f"{self.emcy_consequence}"
            )
        at = self.heartbeat_at
        if at is None:
            return None
        if consumer_ms and now_s - at > consumer_ms / 1000.0:
            return self.heartbeat_reason, (
                f"no heartbeat of {self.name} for {now_s - at:.3f} s "
                f"(1016h consumer time {consumer_ms} ms)"
            )
        if self.state != NMT_OPERATIONAL:
            what = "boot-up" if self.state == NMT_BOOTUP else "NMT state"
            return self.state_reason, (
                f"{self.name} heartbeat reports {what} 0x{self.state:02X}, not operational (0x05)"
            )
        return None
