"""Instructions per lockstep control cycle, counted by valgrind's callgrind (repeatable on a
shared machine, unlike its clock). Developer tool, not part of the packages.

    python tools/lockstep_instructions.py [--cycles 2000] [--record] [--drive-sync]

runs itself under ``valgrind --tool=callgrind --collect-atstart=no
--toggle-collect=functools_reduce`` and prints the instructions per cycle of the paper's
section X through the full stack (``hil bench``'s lockstep run; ``--record``: with the
trace file and the candump log). Only what runs inside one ``functools.reduce`` call is
counted: the whole ``play_references`` (the start-up is not). ``--drive-sync`` counts instead
the drive's Python from its SYNC frame (listener entry) to its second TPDO handed to the bus:
the sends and the physics step after the TPDOs run in nested ``reduce`` calls, which toggle
the count off again. Needs valgrind (the numba cache gets one more entry for valgrind's CPU
on the first run: that run is slow). Run from the checkout: ``cd`` there first.
"""

from __future__ import annotations

import argparse
import functools
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _inner(cycles: int, record: bool, drive_sync: bool) -> None:
    sys.path.insert(0, str(ROOT))
    from hil import bench
    from hil.commands.common import simulated_axis_file
    from hil.harness import play_references, simulated_axis
    from plant_sim.drive.node import GuardedListener
    from plant_sim.drive.servo import ServoAxis
    from plant_sim.paper.scenarios import SectionX
    from virtual_bus.shipped import PAPER_AXIS

    axis = simulated_axis_file(PAPER_AXIS)
    end_s = cycles * axis.control.position_cycle
    refs = SectionX(end_s=end_s, stop_s=min(SectionX.stop_s, end_s)).references(axis)

    def counted(call):  # type: ignore[no-untyped-def]
        return functools.reduce(lambda _a, _b: call(), [0, 0])

    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        with simulated_axis(
            axis,
            bench._params(axis),
            trace_path=tmp_path / "trace.csv" if record else None,
            keep_trace=False,
            disturbance=refs.disturbance_nm if record else None,
            bus_log_path=tmp_path / "bus.log" if record else None,
        ) as sim:
            if not drive_sync:
                run = counted(lambda: play_references(sim, refs))
            else:
                listen = GuardedListener.on_message_received
                advance = ServoAxis.advance
                send = sim.drive_bus.send

                def on_message(self, msg):  # type: ignore[no-untyped-def]
                    if msg.arbitration_id == 0x80:
                        counted(lambda: listen(self, msg))
                    else:
                        listen(self, msg)

                GuardedListener.on_message_received = on_message  # type: ignore[method-assign]
                ServoAxis.advance = lambda self: counted(lambda: advance(self))  # type: ignore[method-assign]
                sim.drive_bus.send = lambda msg, timeout=None: counted(lambda: send(msg, timeout))  # type: ignore[method-assign]
                run = play_references(sim, refs)
    print(f"cycles {run.cycles}, missed TPDOs {run.counters.missed}, {run.state.name}")


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=2000)
    parser.add_argument("--record", action="store_true")
    parser.add_argument("--drive-sync", action="store_true")
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.cycles < 1:
        print(f"--cycles {args.cycles}: must be >= 1", file=sys.stderr)
        return 2
    if args.inner:
        _inner(args.cycles, args.record, args.drive_sync)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "callgrind.out"
        command = [
            "valgrind",
            "--tool=callgrind",
            "--fair-sched=yes",
            "--collect-atstart=no",
            "--toggle-collect=functools_reduce",
            f"--callgrind-out-file={out}",
            sys.executable,
            __file__,
            "--inner",
            f"--cycles={args.cycles}",
            *(["--record"] if args.record else []),
            *(["--drive-sync"] if args.drive_sync else []),
        ]
        env = dict(os.environ, PYTHONHASHSEED="0")
        done = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    collected = re.search(r"Collected : (\d+)", done.stderr)
    if done.returncode != 0 or collected is None:
        print(done.stdout + done.stderr[-2000:], file=sys.stderr)
        return 1
    what = "drive SYNC -> 2nd TPDO" if args.drive_sync else "cycle"
    print(done.stdout.strip())
    print(f"instructions per {what}: {int(collected.group(1)) // args.cycles}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
