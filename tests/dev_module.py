"""``dev.py`` (a script at the checkout's top, not in a package) loaded once as the module
``dev``, for the tests of its commands."""

from __future__ import annotations

import importlib.util
import sys

from tests.paths import ROOT

spec = importlib.util.spec_from_file_location("dev", ROOT / "dev.py")
assert spec is not None and spec.loader is not None
dev = importlib.util.module_from_spec(spec)
sys.modules["dev"] = dev  # dataclasses look their module up there
spec.loader.exec_module(dev)
