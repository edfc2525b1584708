"""The file formats both ends share: the axis file (``axis``, ``docs/axis-file.md``), the
servo trace (``trace``, ``docs/trace-file.md``) and the check that a file is an EDS at all
(``eds``), with one error root (:class:`~virtual_bus.formats.errors.FormatError`)."""

from .eds import EdsFileError
from .errors import AxisFileError, FormatError, TraceFileError, TraceWarning

__all__ = ["AxisFileError", "EdsFileError", "FormatError", "TraceFileError", "TraceWarning"]
