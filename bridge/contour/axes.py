"""The contour axes of a machine: each interpolated axis's name, CANopen node ID and limits,
checked together before any axis moves.

Two axes interpolating one contour share one bus and one SYNC (paper section II.A); their
node IDs must differ (a second drive answering the same COB-IDs would corrupt both), each
must be a CiA 301 node ID (1..127) other than the bridge's own (the SYNC producer and master,
``bridge_node_id``, default :data:`bridge.od.DEFAULT_NODE_ID`), and their names must differ
(a program's X and Y words address them). The limits are :class:`.planner.AxisLimits`
(travel, speed, acceleration), which :func:`.planner.plan` checks every block against.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..errors import ContourError
from ..od import DEFAULT_NODE_ID
from .planner import AxisLimits


@dataclass(frozen=True)
class ContourAxis:
    """One interpolated axis: its limits (and name) and the node ID of its drive."""

    limits: AxisLimits
    node_id: int

    def __post_init__(self) -> None:
        n = self.node_id
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 127:
            raise ContourError(
                f"axis {self.limits.name}: node ID {n!r} not allowed; a CANopen node ID is 1..127"
            )

    @property
    def name(self) -> str:
        return self.limits.name


@dataclass(frozen=True)
class ContourAxes:
    """The axes of one contour (x first, then y), checked as a whole."""

    axes: tuple[ContourAxis, ...]
    bridge_node_id: int = DEFAULT_NODE_ID

    def __post_init__(self) -> None:
        axes = tuple(self.axes)
        object.__setattr__(self, "axes", axes)
        if len(axes) != 2:
            raise ContourError(f"a planar contour has two axes, not {len(axes)}")
        seen: dict[int, str] = {}
        for a in axes:
            if a.node_id == self.bridge_node_id:
                raise ContourError(
                    f"axis {a.name}: node ID {a.node_id} is the bridge's own; give its drive "
                    f"another node ID (1..127 except {self.bridge_node_id})"
                )
            if a.node_id in seen:
                raise ContourError(
                    f"node ID {a.node_id} given to axis {seen[a.node_id]} and axis {a.name}: "
                    "the drives of one bus need different node IDs"
                )
            seen[a.node_id] = a.name
        if axes[0].name == axes[1].name:
            raise ContourError(f"two axes named {axes[0].name!r}: the axes need different names")

    @property
    def limits(self) -> Sequence[AxisLimits]:
        return tuple(a.limits for a in self.axes)
