"""Paths and node-IDs the tests against third-party programs share."""

from __future__ import annotations

from tests.paths import CONFIG

AXIS_FILE = CONFIG / "paper_axis.toml"
DRIVE_EDS = CONFIG / "drive.eds"
BRIDGE_EDS = CONFIG / "bridge.eds"
#: The bridge, the simulated drive, and CANopenNode's canopend (as master or demo slave).
BRIDGE_ID, DRIVE_ID, GATEWAY_ID = 1, 2, 5
