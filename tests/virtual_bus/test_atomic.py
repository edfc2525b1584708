"""Files written whole (virtual_bus/atomic.py): the new content replaces the old only when
complete; a writer that fails leaves the old file and no temporary one; a new file gets the
permissions the umask gives, not a temporary file's 0600. (What a kill leaves: the store's
kill test, tests/bridge/test_store.py, and the demo's, tests/hil/test_kill.py.)"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from virtual_bus.atomic import replacing, write_atomic


def test_the_new_content_replaces_the_old_whole(tmp_path: Path) -> None:
    path = tmp_path / "summary.json"
    write_atomic(path, "old\n")
    with replacing(path) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".summary.json.")
        assert tmp.suffix == ".tmp"  # no reader's pattern (*.csv, *.log, *.json) matches it
        tmp.write_text("half")
        assert path.read_text() == "old\n"  # until the block ends
        tmp.write_text("new\n")
    assert path.read_text() == "new\n"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]


def test_a_failed_writer_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "fig8.png"
    write_atomic(path, b"old")
    with pytest.raises(ZeroDivisionError), replacing(path) as tmp:
        tmp.write_bytes(b"part")
        _ = 1 / 0
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["fig8.png"]


@pytest.mark.parametrize("durable", [False, True])
def test_a_new_file_has_the_umasks_permissions(tmp_path: Path, durable: bool) -> None:
    old = os.umask(0o022)
    try:
        write_atomic(tmp_path / "a.toml", "x = 1\n", durable=durable)
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.toml").stat().st_mode) == 0o644
