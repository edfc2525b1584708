"""The exception root of the developer tools."""

from __future__ import annotations


class ToolsError(Exception):
    """Root of the errors the developer tools raise."""


class RegistryError(ToolsError, ValueError):
    """The benchmark registry (``tools/benches.toml``) is not what the loader allows: the
    message names the file, the benchmark and the key."""
