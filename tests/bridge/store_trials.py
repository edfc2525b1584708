"""What the store's kill test (tests/bridge/test_store.py) runs in a forked child
(tests/forking.py): the store saved with two sets of values in turn, forever."""

from __future__ import annotations

from bridge.store import ParameterStore

#: The two sets of raw values (2000h:00 k_v as REAL32, 2002h:00 beta_T, 2014h:01 a limit).
OLD = {(0x2000, 0): bytes.fromhex("0000c841"), (0x2014, 1): bytes.fromhex("00000040")}
NEW = {(0x2000, 0): bytes.fromhex("0000f041"), (0x2002, 0): bytes.fromhex("0ad7a33f")}


def save_in_turn(path: str) -> int:
    store = ParameterStore(path)
    while True:
        store.save(NEW)
        store.save(OLD)
