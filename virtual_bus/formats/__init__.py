"""The file formats both ends share: the axis file (``axis``, ``docs/axis-file.md``) and the
servo trace (``trace``, ``docs/trace-file.md``), with their checks and one error root
(:class:`~virtual_bus.formats.errors.FormatError`)."""

from .errors import AxisFileError, FormatError, TraceFileError, TraceWarning

__all__ = ["AxisFileError", "FormatError", "TraceFileError", "TraceWarning"]
