"""Helpers of the start-up tests: python canopen's own LocalNode, built from a vendor's EDS,
answers the bridge's SDO client over a python-can ``virtual`` bus.

A LocalNode is a plain SDO server on the EDS: it stores what is written and serves EDS
defaults. It runs no CiA 402 state machine and no mode switch; the only thing added here is
:func:`mirror_mode`, which copies a 6060h write into 6061h (what every CiA 402 drive shows),
so that the start-up's "wait until 6061h shows the mode" can finish. Everything else the
tests check is what the LocalNode stored.
"""

from __future__ import annotations

import contextlib
import os
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import canopen
import pytest

from bridge.master import DriveMaster, DriveSetup
from tests.paths import DATA
from virtual_bus.formats.drive_profile import DriveProfile
from virtual_bus.shipped import SHARED_DIR

#: The vendors' EDS files are third-party data: they are not part of this repository but of
#: the shared data beside it (``shared/vendor_eds/``, with their sources and licences in its
#: README); ``BACKLASH_VENDOR_EDS`` points elsewhere. Tests that need one skip without it.
VENDOR_EDS = Path(os.environ.get("BACKLASH_VENDOR_EDS") or SHARED_DIR / "vendor_eds")
TECHNOSOFT_EDS = VENDOR_EDS / "technosoft_ipos.eds"
YIYOU_EDS = VENDOR_EDS / "yiyou_euservo.eds"


def require_eds(path: Path) -> Path:
    """``path``, or skip the test that needs it with the reason."""
    if not path.is_file():
        pytest.skip(f"vendor EDS {path.name} not found in {VENDOR_EDS} (shared/vendor_eds)")
    return path


ENCODER_EDS = DATA / "cia406_encoder.eds"
SETUP = DriveSetup(sdo_timeout_s=2.0, state_timeout_s=2.0)


def mirror_mode(node: canopen.LocalNode) -> None:
    """6060h written -> 6061h shows it (the one drive behaviour the tests emulate)."""

    def on_write(index: int, subindex: int, od: object, data: bytes) -> None:
        if index == 0x6060:
            node.data_store.setdefault(0x6061, {})[0] = bytes(data)

    node.add_write_callback(on_write)


@dataclass
class Rig:
    """LocalNodes on one side, the bridge's SDO client (``master``) on the other."""

    nodes: dict[int, canopen.LocalNode]
    master: DriveMaster
    client: canopen.Network
    channel: str

    def stored(self, node_id: int, index: int, subindex: int) -> int:
        """What the LocalNode holds now (written value, else the EDS default), as integer."""
        node = self.nodes[node_id]
        return int.from_bytes(node.get_data(index, subindex), "little", signed=False)


@contextlib.contextmanager
def local_rig(
    eds: Path,
    profile: DriveProfile | None = None,
    drive_id: int = 2,
    extra: dict[int, Path] | None = None,
    load_increments_per_unit: float = 1e9,
) -> Iterator[Rig]:
    """A LocalNode of ``eds`` (node ``drive_id``) and of each ``extra`` EDS, and a
    :class:`DriveMaster` for the drive, on a fresh virtual channel; all shut down after."""
    channel = f"adapt-{uuid.uuid4().hex[:12]}"
    server = canopen.Network()
    client = canopen.Network()
    server.NOTIFIER_CYCLE = client.NOTIFIER_CYCLE = 0.02  # bounds the join at disconnect
    nodes: dict[int, canopen.LocalNode] = {}
    server.connect(interface="virtual", channel=channel)
    try:
        client.connect(interface="virtual", channel=channel)
        try:
            for node_id, path in {drive_id: require_eds(eds), **(extra or {})}.items():
                node = canopen.LocalNode(node_id, canopen.import_od(str(path), node_id))
                mirror_mode(node)
                server.add_node(node)
                nodes[node_id] = node
            remote = canopen.RemoteNode(drive_id, canopen.ObjectDictionary())
            client.add_node(remote)
            master = DriveMaster(
                remote, SETUP, profile=profile, load_increments_per_unit=load_increments_per_unit
            )
            try:
                yield Rig(nodes, master, client, channel)
            finally:
                for node in nodes.values():
                    node.nmt.stop_heartbeat()
        finally:
            client.disconnect()
    finally:
        server.disconnect()


#: Two drives the project was not written against (shared/vendor_eds/README.md): Faulhaber's
#: MCBL 300x CO (profile velocity, writable mappings of 4 entries, no 6077h/60E4h) and MCBL-CF
#: (no 6502h, a static mapping: 6064h/606Ch/60FFh not PDO-mappable).
FAULHABER_CO_EDS = VENDOR_EDS / "faulhaber_mcbl_co.eds"
FAULHABER_CF_EDS = VENDOR_EDS / "faulhaber_mcbl_cf.eds"
