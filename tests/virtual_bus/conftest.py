"""Fixtures of the bus tests."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable

import pytest

from virtual_bus.netns import NetworkNamespace


@pytest.fixture
def netns_script(
    private_netns: NetworkNamespace, subprocess_env: dict[str, str]
) -> Callable[[str], dict]:
    """Runs a python script inside a private network namespace (it must exit 0); returns the
    JSON object its last line of output prints."""

    def run(script: str) -> dict:
        argv = [sys.executable, "-c", script]
        done = private_netns.run(argv, timeout_s=60, env=subprocess_env)
        assert done.returncode == 0, done.stderr
        return json.loads(done.stdout.strip().splitlines()[-1])

    return run
