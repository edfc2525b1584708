"""The files the project ships in ``config/``: the EDS of both nodes and the axis files.

One place names them for every package. In a source checkout (or an editable install) they
are the checkout's ``config/``; a wheel installs the same files under
``<prefix>/share/backlash-bridge/config`` (``[tool.setuptools.data-files]`` of
``pyproject.toml``), which is used when there is no checkout.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

_CHECKOUT = Path(__file__).resolve().parents[1] / "config"
_INSTALLED = Path(sys.prefix) / "share" / "backlash-bridge" / "config"

#: the folder of the shipped files
CONFIG_DIR = _CHECKOUT if _CHECKOUT.is_dir() else _INSTALLED
#: the bridge's EDS (CiA 306), rendered from :mod:`bridge.od` by ``bridge eds``
BRIDGE_EDS = CONFIG_DIR / "bridge.eds"
#: the simulated drive's EDS (CiA 306), the contract's object dictionary
DRIVE_EDS = CONFIG_DIR / "drive.eds"
#: section IX's milling-machine axis as the paper gives it
PAPER_AXIS = CONFIG_DIR / "paper_axis.toml"

#: Third-party material beside the checkout (the paper, public recordings, vendor EDS files,
#: CANopenNode's source), never part of the repository: ``$BACKLASH_SHARED``, else
#: ``shared/`` next to the checkout. What needs it says so and skips where it is absent.
SHARED_DIR = Path(os.environ.get("BACKLASH_SHARED") or _CHECKOUT.parents[1] / "shared")
#: a family of feed axes as an FMI 2.0 co-simulation FMU, written apart from this project
#: (``shared/plants/README.md``; docs/fmu.md)
AXIS_FAMILY_FMU = SHARED_DIR / "plants" / "axis_family.fmu"
