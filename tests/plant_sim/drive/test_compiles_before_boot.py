"""The simulated drive compiles before its boot-up (issue 21, a first run on a busy machine).

A numba function is compiled (or loaded from the cache) at its first call. On an empty cache
and a loaded 2-core machine one compile takes seconds, longer than a master's SDO timeout
(0.3 s x 3 for the bridge's start-up): a drive that compiled on its first SDO read of
6064h:00 made ``bridge demo`` fail with "no SDO answer". So every compiled function the drive
calls must have its machine code before the boot-up message. Checked against numba's own
bookkeeping: in a fresh interpreter, no compiled function of the kernel gains a signature
after ``start()``, while python canopen's master reads every object of the drive's EDS and
steps the drive through SYNCs in Switch on disabled and in Operation enabled.
"""

from __future__ import annotations

import json
import subprocess
import sys

from tests.paths import ROOT

CHILD = r"""
import json, sys, uuid
import can, canopen
from numba.core.dispatcher import Dispatcher
import plant_sim.physics.kernel as K
from virtual_bus.formats.axis import load_axis
from plant_sim.drive import SimulatedDrive
from virtual_bus import BusConfig, Interface, open_bus

def signatures():
    return {n: len(d.overloads) for n, d in vars(K).items() if isinstance(d, Dispatcher)}

config = BusConfig(interface=Interface.VIRTUAL, channel=f"warm-{uuid.uuid4().hex[:10]}")
drive_bus, master_bus = open_bus(config), open_bus(config)
drive = SimulatedDrive(drive_bus, 2, load_axis("config/paper_axis.toml"))
before_start = signatures()
drive.start()
after_start = signatures()
network = canopen.Network(master_bus)
network.NOTIFIER_CYCLE = 0.05
network.connect()
node = network.add_node(2, "config/drive.eds")
reads = 0
for obj in node.object_dictionary.values():
    for var in (obj.values() if hasattr(obj, "values") else [obj]):
        if "r" in var.access_type:
            try:
                node.sdo.upload(var.index, var.subindex)
            except canopen.SdoAbortedError:
                pass
            reads += 1
def syncs(n):
    for _ in range(n):
        network.sync.transmit()
        node.sdo.upload(0x6041, 0)  # answered after the SYNC: the step is done
for cw in (0x06, 0x07, 0x0F):
    syncs(3)
    node.sdo.download(0x6040, 0, cw.to_bytes(2, "little"))
syncs(5)
state = node.sdo.upload(0x6041, 0)
network.disconnect()
drive.stop()
drive_bus.shutdown()
master_bus.shutdown()
print(json.dumps({"before_start": before_start, "after_start": after_start,
                  "after_use": signatures(), "reads": reads,
                  "statusword": int.from_bytes(state, "little")}))
"""


def test_no_compiled_function_is_first_called_after_the_boot_up() -> None:
    done = subprocess.run(
        [sys.executable, "-c", CHILD], cwd=ROOT, capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    got = json.loads(done.stdout.splitlines()[-1])
    assert not any(got["before_start"].values())  # a fresh interpreter: nothing loaded yet
    assert got["reads"] > 100  # every readable object of the EDS
    assert got["statusword"] & 0x6F == 0x27  # Operation enabled (CiA 402): advance ran
    assert got["after_use"] == got["after_start"]
