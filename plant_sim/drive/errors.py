"""Exceptions of :mod:`plant_sim.drive`, all below :class:`plant_sim.errors.PlantSimError`.

SDO abort codes are :class:`virtual_bus.contract.SdoAbort`; a refused SDO write
raises :class:`DriveSdoAbort`, which the canopen SDO server turns into an abort frame with
``code`` (it is also a :class:`canopen.SdoAbortedError`).
"""

from __future__ import annotations

from canopen.sdo import SdoAbortedError

from plant_sim.errors import PlantSimError


class DriveError(PlantSimError):
    """Root of every error raised by :mod:`plant_sim.drive`."""


class DriveConfigError(DriveError, ValueError):
    """A :class:`plant_sim.drive.DriveConfig` value or constructor argument is out of range."""


class DriveEdsError(DriveError, ValueError):
    """The EDS does not fit the drive (missing object, wrong data type or access, a writable
    object the drive does not implement). ``key`` is ``(index, subindex)`` where known."""

    def __init__(self, message: str, *, key: tuple[int, int] | None = None) -> None:
        super().__init__(message)
        self.key = key


class DriveInputError(DriveError, ValueError):
    """A value given to the drive's Python API (e.g. a disturbance) is out of range."""


class DriveStateError(DriveError, RuntimeError):
    """The drive's Python API was used in the wrong lifecycle state (e.g. started twice)."""


class DriveSdoAbort(DriveError, SdoAbortedError):
    """An SDO write was refused; nothing was changed.

    ``code`` is the CiA 301 SDO abort code sent to the client, ``key`` the object
    ``(index, subindex)``; the message says what was wrong and what is allowed.
    """

    def __init__(self, code: int, message: str, *, key: tuple[int, int] | None = None) -> None:
        SdoAbortedError.__init__(self, code)
        Exception.__init__(self, message)
        self.key = key
        self.message = message

    def __str__(self) -> str:
        where = f"{self.key[0]:04X}h:{self.key[1]:02X} " if self.key else ""
        return f"{where}SDO abort 0x{self.code:08X}: {self.message}"

    __hash__ = Exception.__hash__
