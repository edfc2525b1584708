"""Paths and node-IDs the tests against third-party programs share."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
AXIS_FILE = REPO / "config" / "paper_axis.toml"
DRIVE_EDS = REPO / "config" / "drive.eds"
BRIDGE_EDS = REPO / "config" / "bridge.eds"
#: The bridge, the simulated drive, and CANopenNode's canopend (as master or demo slave).
BRIDGE_ID, DRIVE_ID, GATEWAY_ID = 1, 2, 5
