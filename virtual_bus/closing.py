"""What ``with`` does for everything in the project that is closed: close it on the way out."""

from __future__ import annotations

from types import TracebackType
from typing import Self


class Closing:
    """A resource whose :meth:`close` frees it; ``with resource:`` closes it on the way out,
    whether the block ended normally or by an exception (which propagates)."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
