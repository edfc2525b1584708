"""Mutants (a mutated file with its verdict) and running them through a reader, the objects
built from what it accepts, or a command line (what :mod:`tests.mutations` is about)."""

from __future__ import annotations

import contextlib
import io
import random
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

from tests.command_line import exit_status


class Verdict(Enum):
    """What the format's documentation says of a mutated file."""

    VALID = "valid"  # must be accepted
    INVALID = "invalid"  # must be refused
    EITHER = "either"  # not decided by the documents


VALID, INVALID, EITHER = Verdict.VALID, Verdict.INVALID, Verdict.EITHER


@dataclass(frozen=True)
class Mutant:
    """One mutated file: ``seed`` (the good file's name), ``what`` was done to it, its bytes,
    the :class:`Verdict` and ``names`` (a key, column or section a refusal should name;
    empty: the file as a whole)."""

    seed: str
    what: str
    data: bytes
    verdict: Verdict
    names: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        return f"{self.seed}: {self.what}"

    def write(self, folder: Path, suffix: str) -> Path:
        """The mutant as a file in ``folder`` (its name says what was done)."""
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", self.what)[:60]
        path = folder / f"{Path(self.seed).stem}-{slug}{suffix}"
        path.write_bytes(self.data)
        return path


class Mutants(list[Mutant]):
    """The mutants of one good file (``seed``), in the order they are added."""

    def __init__(self, seed: str) -> None:
        super().__init__()
        self.seed = seed

    def add(self, what: str, data: str | bytes, verdict: Verdict, *names: str) -> None:
        """One more: ``data`` (text is written as UTF-8), its verdict, what a refusal names."""
        raw = data.encode("utf-8") if isinstance(data, str) else data
        self.append(Mutant(self.seed, what, raw, verdict, names))


def garbage(rng: random.Random, size: int = 300) -> bytes:
    """Random bytes with a NUL and an invalid UTF-8 sequence in them."""
    return bytes(rng.randrange(256) for _ in range(size)) + b"\x00\xff\xfe"


def mutants_of(seeds: Sequence[Path], make: Any, first_seed: int = 0) -> list[Mutant]:
    """``make(name, text, rng_seed)`` over the seed files, each with its own seeded generator."""
    out: list[Mutant] = []
    for i, path in enumerate(seeds):
        out += make(path.name, path.read_text(encoding="utf-8"), first_seed + i)
    return out


# --- running them ------------------------------------------------------------------------------
@dataclass
class Findings:
    """What the mutants did to one reader (or to what is built from an accepted file)."""

    accepted: dict[Mutant, Any] = field(default_factory=dict)
    refused: dict[Mutant, BaseException] = field(default_factory=dict)
    tracebacks: list[str] = field(default_factory=list)
    accepted_invalid: list[str] = field(default_factory=list)
    refused_valid: list[str] = field(default_factory=list)
    bad_messages: list[str] = field(default_factory=list)

    def problems(self) -> list[str]:
        return [
            *(f"traceback: {p}" for p in self.tracebacks),
            *(f"accepted though invalid: {p}" for p in self.accepted_invalid),
            *(f"refused though valid: {p}" for p in self.refused_valid),
            *(f"message: {p}" for p in self.bad_messages),
        ]

    def summary(self) -> str:
        return (
            f"{len(self.accepted) + len(self.refused)} mutants: {len(self.refused)} refused, "
            f"{len(self.accepted)} accepted; {len(self.tracebacks)} tracebacks, "
            f"{len(self.accepted_invalid)} accepted though invalid"
        )


def attempt(
    findings: Findings,
    label: str,
    call: Any,
    errors: tuple[type[BaseException], ...],
) -> tuple[bool, Any]:
    """``(True, call())`` or ``(False, the refusal)`` when ``call`` raises one of ``errors``
    (the packages' own) in one line; anything else raised is a traceback a user would see
    and is noted in ``findings``."""
    try:
        return True, call()
    except errors as exc:
        if "\n" in str(exc).strip() or not str(exc).strip():
            findings.bad_messages.append(f"{label}: not one line: {str(exc)!r}")
        return False, exc
    except Exception as exc:  # a builtin error: what these tests look for
        findings.tracebacks.append(f"{label}: {type(exc).__name__}: {exc}"[:300])
        return False, exc


def load_each(
    mutants: Sequence[Mutant],
    folder: Path,
    suffix: str,
    load: Any,
    errors: tuple[type[BaseException], ...],
) -> Findings:
    """Every mutant written to ``folder`` and given to ``load(path)``: verdicts kept, and a
    refusal must name the file and (when the mutant says which) the key, column or section."""
    findings = Findings()
    for m in mutants:
        path = m.write(folder, suffix)
        ok, result = attempt(findings, m.label, lambda p=path: load(p), errors)
        if ok:
            findings.accepted[m] = result
            if m.verdict is INVALID:
                findings.accepted_invalid.append(m.label)
            continue
        if not isinstance(result, errors):
            continue  # a traceback, noted
        findings.refused[m] = result
        message = str(result)
        if m.verdict is VALID:
            findings.refused_valid.append(f"{m.label}: {message}")
        if path.name not in message:
            findings.bad_messages.append(f"{m.label}: does not name the file: {message}")
        elif m.names and not any(n.rsplit(".", 1)[-1] in message for n in m.names):
            findings.bad_messages.append(f"{m.label}: does not name {m.names}: {message}")
    return findings


def run_cli(
    findings: Findings, label: str, main: Any, argv: Sequence[str], bad_file: str = ""
) -> int | None:
    """Run a command line in process (``main(argv)`` of a package's ``__main__``); its exit
    status, or None after an exception escaped (noted in ``findings`` as a traceback). A
    failing status must come with exactly one error line on stderr (``warning:`` lines
    aside), naming ``bad_file`` when given."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = exit_status(main, argv)
    except Exception as exc:  # a builtin error: what these tests look for
        findings.tracebacks.append(f"{label}: {' '.join(argv[:1])}: {type(exc).__name__}: {exc}")
        return None
    lines = [line for line in err.getvalue().splitlines() if not line.startswith("warning:")]
    if code != 0 and (len(lines) != 1 or ": error: " not in lines[0] or bad_file not in lines[0]):
        findings.bad_messages.append(f"{label}: {argv[0]} exit {code}, stderr {lines}")
    return int(code or 0)
