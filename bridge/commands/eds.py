"""``python -m bridge eds``: the bridge's EDS (CiA 306) from bridge.od.OBJECTS.

Prints it on stdout; ``--out FILE`` writes it (``--out config/bridge.eds`` updates the
tracked file); ``--check`` compares a file with it (default: config/bridge.eds).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from virtual_bus.atomic import write_atomic

from .. import od as objdict
from ..eds import render_eds
from .common import PROG

NAME = "eds"
HELP = "print the bridge's EDS (--out FILE writes it, --check compares config/bridge.eds)"
DESCRIPTION = "Renders the bridge's EDS (CiA 306) from bridge.od.OBJECTS."


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help=f"write it here instead of stdout (the tracked file: {objdict.DEFAULT_EDS_PATH})",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="exit 1 if the file (--out, default the tracked one) differs",
    )


def run(args: argparse.Namespace) -> int:
    text = render_eds()
    if args.check:
        path = args.out or objdict.DEFAULT_EDS_PATH
        current = path.read_text(encoding="utf-8") if path.is_file() else None
        if current != text:
            print(f"{path}: differs from bridge.od.OBJECTS (run `{PROG} eds --out {path}`)")
            return 1
        print(f"{path}: up to date")
        return 0
    if args.out is None:
        sys.stdout.write(text)
        return 0
    write_atomic(args.out, text)
    print(f"wrote {args.out}")
    return 0
