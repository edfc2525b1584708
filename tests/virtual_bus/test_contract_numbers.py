"""The CiA 301/402/406 numbers are written once, in :mod:`virtual_bus.contract` (issue 27).

Every other module names an object by the contract's enums (``Cia402.STATUSWORD``, ...) and an
EMCY code by its constant, so a number typed twice cannot drift. The check reads the code's
tokens (``tokenize``): a hexadecimal literal in code whose value is one of the contract's
object indices or EMCY codes is an offence; comments, docstrings and messages may say
``6041h`` as a reader would.
"""

from __future__ import annotations

import io
import tokenize
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.paths import ROOT
from virtual_bus import contract

#: the product's packages (tests may write numbers: they are the other side's oracle)
PACKAGES = ("bridge", "cmdline", "diagnosis", "fleet", "hil", "plant_sim", "reference_plants")
PACKAGES += ("regulator", "tools", "virtual_bus")
THE_CONTRACT = ROOT / "virtual_bus" / "contract.py"


def contract_numbers() -> frozenset[int]:
    """The object indices and EMCY codes the contract defines."""
    indices = {int(m) for e in (contract.Cia301, contract.Cia402, contract.Cia406) for m in e}
    emcy = {v for k, v in vars(contract).items() if k.startswith("EMCY_") and isinstance(v, int)}
    return frozenset(indices | {int(v) for v in emcy if v >= 0x1000})  # codes, not COB-ID/length


def offences(source: str, numbers: frozenset[int]) -> Iterator[tuple[int, str]]:
    """(line, literal) of every hexadecimal literal in ``source`` whose value is a contract
    number; decimal literals are values, not object names."""
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        text = tok.string.lower()
        hexadecimal = tok.type == tokenize.NUMBER and text.startswith("0x")
        if hexadecimal and int(text.replace("_", ""), 16) in numbers:
            yield tok.start[0], tok.string


def product_files() -> list[Path]:
    files = [p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]
    return [p for p in files if p != THE_CONTRACT]


def test_the_scanner_finds_a_number_typed_by_hand() -> None:
    numbers = contract_numbers()
    source = 'KEY = (0x6041, 0)  # 0x6064 in a comment is fine\ndoc = "0x60FF"\nN = 0x1236\n'
    assert list(offences(source, numbers)) == [(1, "0x6041")]
    assert 0x6041 in numbers and 0x8130 in numbers and 0x1018 in numbers


def test_the_contract_names_each_number_once() -> None:
    values = [int(m) for e in (contract.Cia301, contract.Cia402, contract.Cia406) for m in e]
    assert len(values) == len(set(values)), "an index named twice"
    assert contract.TPDO_MAPPING_BASE == contract.Cia301.TPDO_MAPPING == 0x1A00
    assert all(i in contract.COMMUNICATION_AREA for i in contract.Cia301)


@pytest.mark.parametrize("path", product_files(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_module_types_a_contract_number(path: Path) -> None:
    found = list(offences(path.read_text(encoding="utf-8"), contract_numbers()))
    assert not found, (
        f"{path.relative_to(ROOT)}: {', '.join(f'line {n}: {lit}' for n, lit in found)} -- "
        "name it by virtual_bus.contract (Cia301/Cia402/Cia406, EMCY_*)"
    )
