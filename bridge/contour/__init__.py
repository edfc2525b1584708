"""Two or more axes interpolated along one contour, and the circular test that judges them.

* :mod:`.path` -- lines and circular arcs (G01, G02, G03) in the plane of two axes;
* :mod:`.program` -- G-code-like text (G01/G02/G03, X Y I J F) to blocks;
* :mod:`.planner` -- the feed profile the axes share (feed, acceleration, jerk, each axis's
  travel, speed and acceleration limits), one position and speed reference per cycle;
* :mod:`.circular` -- the circular test of ISO 230-4 (radius, feed, both directions);
* :mod:`.ballbar` -- its evaluation: ISO 230-4's figures and a ballbar report's decomposition
  (reversal spikes, backlash per axis, servo mismatch, scale mismatch, squareness);
* :mod:`.compensation` -- a CNC's backlash compensation on the speed set point;
* :mod:`.figures` -- the magnified polar plot (matplotlib, imported only when drawing).

The bridge's floor: numpy only, no simulator (docs/contour.md).
"""

from .ballbar import BallbarReport, MeasuredPath, analyse
from .circular import CircularTest, Direction
from .path import Arc, Line
from .planner import AxisLimits, Block, ContourReference, PathLimits, plan

__all__ = [
    "Arc",
    "AxisLimits",
    "BallbarReport",
    "Block",
    "CircularTest",
    "ContourReference",
    "Direction",
    "Line",
    "MeasuredPath",
    "PathLimits",
    "analyse",
    "plan",
]
