"""An FMI 2.0 co-simulation FMU as an axis: loaded, checked, instantiated.

:func:`load_fmu` checks everything that can be checked before a bus is touched and says in
one line what is wrong:

1. the file is a zip archive and FMPy's model-description validation passes
   (``fmpy.read_model_description(validate=True)``: the schema, unique names, value
   references, units);
2. FMI 2.0 with co-simulation (a model-exchange-only FMU has no solver of its own) and a
   binary for this platform;
3. every mapped variable (:mod:`.mapping`) exists, is a Real of the right causality (the
   set point an input, the measurements outputs) and its unit is one of its quantity
   (:mod:`.units`);
4. every parameter given (``--fmu-param seed=7``) exists, is a parameter the FMU lets a user
   set (causality ``parameter``, variability fixed or tunable) and its text is a value of the
   variable's type;
5. one instance is made, initialised and freed: an FMU that fails ``fmi2Instantiate`` or its
   initialisation is refused with the messages it logged; its data-sheet values
   (calculated parameters, read after ``fmi2ExitInitializationMode``) are kept.

The archive is extracted once per content into ``$XDG_CACHE_HOME/backlash-bridge/fmu/SHA``
(atomically: a second process either finds it complete or extracts its own and renames).
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import shutil
import tempfile
import threading
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import FmuError, FmuStepError
from .mapping import MEASURED, Binding, FmuMapping, Signal, parse_parameters
from .units import Quantity, factor

#: Parameter types this loader sets, by FMI 2.0 type name.
_SETTABLE = ("Real", "Integer", "Boolean")


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/backlash-bridge/fmu`` (default ``~/.cache/backlash-bridge/fmu``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "backlash-bridge" / "fmu"


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:20]


def _extract(path: Path, digest: str) -> Path:
    target = cache_dir() / digest
    if (target / "modelDescription.xml").is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{digest}-", dir=target.parent))
    try:
        with zipfile.ZipFile(path) as archive:
            archive.extractall(tmp)
        try:
            tmp.rename(target)
        except OSError:  # another process was first: its copy is the same content
            if not (target / "modelDescription.xml").is_file():
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return target


@dataclass(frozen=True)
class ParameterValue:
    name: str
    reference: int
    type: str  # "Real", "Integer", "Boolean"
    value: float | int | bool


@dataclass(frozen=True)
class SignalPort:
    """A mapped signal: value reference, its quantity and factor to SI (value_SI = raw*factor)."""

    signal: Signal
    variable: str
    reference: int
    quantity: Quantity
    factor: float


@dataclass(frozen=True)
class FmuSpec:
    """An FMU as an axis, as a command line gives it: file, parameters, mapping. Small and
    picklable (what a Dask task carries); :meth:`load` checks it (module docstring)."""

    path: Path
    parameters: tuple[tuple[str, str], ...] = ()
    mapping: FmuMapping = field(default_factory=FmuMapping)

    @classmethod
    def from_text(cls, path: str | Path, params: str = "", mapping: str = "") -> FmuSpec:
        """``--fmu PATH --fmu-param seed=7,family=1 --fmu-map ...``."""
        return cls(
            Path(path),
            tuple(parse_parameters(params).items()),
            FmuMapping().with_text(mapping) if mapping else FmuMapping(),
        )

    def with_parameters(self, **values: object) -> FmuSpec:
        merged = dict(self.parameters) | {k: str(v) for k, v in values.items()}
        return FmuSpec(self.path, tuple(merged.items()), self.mapping)

    def parameter(self, name: str) -> str | None:
        return dict(self.parameters).get(name)

    def describe(self) -> str:
        params = ",".join(f"{k}={v}" for k, v in self.parameters)
        return f"{self.path.name}" + (f" ({params})" if params else "")

    def load(self) -> FmuModel:
        return load_fmu(self)


class FmuModel:
    """A checked FMU (module docstring): what :class:`plant_sim.fmu.FmuPlant` instantiates.

    Attributes: ``spec``; ``guid``, ``model_identifier``, ``unzip_dir``; ``set_point`` and
    ``disturbance`` (:class:`SignalPort`, the latter None when unmapped), ``measured`` (the
    four outputs in :data:`plant_sim.fmu.mapping.MEASURED` order); ``parameters`` (set on
    every instance); ``nominal`` (every calculated parameter's value after initialisation
    with these parameters); ``step_size_s`` (the FMU's default experiment step, or None).
    """

    def __init__(self, spec: FmuSpec) -> None:
        self.spec = spec
        path = spec.path
        self._check_archive(path)
        md = self._read_description(path)
        if md.fmiVersion != "2.0":
            raise FmuError(
                f"FMU {path}: FMI {md.fmiVersion}; this loader runs FMI 2.0 co-simulation "
                "(export the model as an FMI 2.0 co-simulation FMU)"
            )
        if md.coSimulation is None:
            raise FmuError(
                f"FMU {path}: model exchange only; the drive steps a co-simulation FMU (it "
                "brings its own solver): export it for co-simulation"
            )
        self.guid: str = md.guid
        self.model_identifier: str = md.coSimulation.modelIdentifier
        self._check_binary(path)
        self.variables = {v.name: v for v in md.modelVariables}
        self.unzip_dir = _extract(path, _digest(path))
        mapping = spec.mapping
        self.set_point = self._port(mapping, Signal.SPEED_SETPOINT)
        self.disturbance = self._port(mapping, Signal.DISTURBANCE)
        self.measured = tuple(self._port(mapping, s) for s in MEASURED)
        self.parameters = tuple(self._parameter(n, t) for n, t in spec.parameters)
        self.initial_position = self._optional_parameter(mapping.initial_position, "Real")
        self.ratio_parameter = self._optional_parameter(mapping.transmission_ratio, "Real")
        experiment = md.defaultExperiment
        step = getattr(experiment, "stepSize", None)
        self.step_size_s: float | None = float(step) if step else None
        self.nominal: dict[str, float] = self._initialise_once()

    # --- checks --------------------------------------------------------------------------------
    @staticmethod
    def _check_archive(path: Path) -> None:
        if not path.is_file():
            raise FmuError(f"FMU {path}: no such file")
        if not zipfile.is_zipfile(path):
            raise FmuError(f"FMU {path}: not an FMU (an FMU is a zip archive; this file is not)")

    @staticmethod
    def _read_description(path: Path) -> Any:
        import fmpy

        try:
            return fmpy.read_model_description(str(path), validate=True)
        except Exception as exc:  # FMPy raises bare Exceptions with the problems listed
            text = " ".join(str(exc).split())
            raise FmuError(f"FMU {path}: invalid model description: {text}") from None

    def _check_binary(self, path: Path) -> None:
        import fmpy

        wanted = f"binaries/{fmpy.platform}/{self.model_identifier}{fmpy.sharedLibraryExtension}"
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
        if wanted not in names:
            have = sorted(
                {n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2}
            )
            raise FmuError(
                f"FMU {path}: no binary for this platform ({wanted}); it has: "
                + (", ".join(have) if have else "no binaries (source only)")
            )

    def _port(self, mapping: FmuMapping, signal: Signal) -> Any:
        binding: Binding | None = mapping.binding(signal)
        if binding is None:
            return None
        where = f"FMU {self.spec.path}: {signal.key} -> {binding.variable!r}"
        v = self.variables.get(binding.variable)
        if v is None:
            candidates = sorted(
                n for n, x in self.variables.items() if x.causality == signal.causality
            )
            raise FmuError(
                f"{where}: no such variable; the FMU's {signal.causality}s: "
                + (", ".join(candidates) or "none")
                + " (map it with --fmu-map)"
            )
        if v.type != "Real":
            raise FmuError(f"{where}: a {v.type}; the drive's signals are Real")
        if v.causality != signal.causality:
            raise FmuError(
                f"{where}: causality {v.causality}; {signal.key} must be an {signal.causality}"
            )
        declared = v.unit or (v.declaredType.unit if v.declaredType is not None else None)
        if declared and binding.unit and declared != binding.unit:
            raise FmuError(
                f"{where}: the FMU declares unit {declared!r}, the mapping says {binding.unit!r}"
            )
        unit = declared or binding.unit
        if not unit:
            raise FmuError(
                f"{where}: the FMU declares no unit; give it in the mapping, e.g. "
                f"--fmu-map {signal.key}={binding.variable}[UNIT]"
            )
        quantity, scale = factor(unit, signal.quantities, where)
        return SignalPort(signal, binding.variable, v.valueReference, quantity, scale)

    def _parameter(self, name: str, text: str) -> ParameterValue:
        v = self.variables.get(name)
        where = f"FMU {self.spec.path}: --fmu-param {name}={text}"
        if v is None:
            settable = sorted(n for n, x in self.variables.items() if x.causality == "parameter")
            raise FmuError(f"{where}: no such parameter; it has: {', '.join(settable) or 'none'}")
        if v.causality != "parameter" or v.variability not in ("fixed", "tunable"):
            raise FmuError(
                f"{where}: {name} is a {v.variability} {v.causality}, not a parameter a user sets"
            )
        if v.type not in _SETTABLE:
            raise FmuError(f"{where}: a {v.type} parameter; settable: {', '.join(_SETTABLE)}")
        return ParameterValue(name, v.valueReference, v.type, _value(v.type, text, where))

    def _optional_parameter(self, name: str | None, type_: str) -> int | None:
        if name is None:
            return None
        v = self.variables.get(name)
        if v is None or v.type != type_:
            return None
        return int(v.valueReference)

    def _initialise_once(self) -> dict[str, float]:
        instance = self.instantiate("check", None)
        try:
            names = [
                n
                for n, v in self.variables.items()
                if v.causality == "calculatedParameter" and v.type == "Real"
            ]
            values = instance.get_real([self.variables[n].valueReference for n in names])
            return dict(zip(names, values, strict=True))
        finally:
            instance.free()

    # --- instances -----------------------------------------------------------------------------
    def instantiate(self, name: str, initial_position: float | None) -> FmuInstance:
        """A new instance, parameters set, initialised (at ``initial_position`` load units)."""
        instance = FmuInstance(self, name)
        try:
            instance.setup(initial_position)
        except BaseException:
            instance.free()
            raise
        return instance

    def transmission_ratio(self) -> float | None:
        name = self.spec.mapping.transmission_ratio
        value = self.nominal.get(name) if name else None
        return value if value and value > 0 else None

    def describe(self) -> str:
        return self.spec.describe()


def _value(type_: str, text: str, where: str) -> float | int | bool:
    try:
        if type_ == "Integer":
            return int(text, 0)
        if type_ == "Boolean":
            low = text.lower()
            if low in ("1", "true"):
                return True
            if low in ("0", "false"):
                return False
            raise ValueError(text)
        value = float(text)
    except ValueError:
        allowed = {"Integer": "an integer", "Boolean": "true or false", "Real": "a number"}
        raise FmuError(f"{where}: not {allowed[type_]}") from None
    return value


# --- the FMU's log -----------------------------------------------------------------------------
_LOGS: dict[int, list[str]] = {}
_LOG_LOCK = threading.Lock()
_LABELS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")


def _route(env: int | None, _name: bytes, status: int, _category: bytes, message: bytes) -> None:
    text = message.decode("utf-8", "replace") if message else ""
    label = _LABELS[status] if 0 <= status < len(_LABELS) else str(status)
    with _LOG_LOCK:
        sink = _LOGS.get(env or 0)
        if sink is not None:
            sink.append(f"{label}: {text}")
            del sink[:-20]  # the last messages are the ones a failure needs


_callbacks_kept: list[Any] = []


def _callbacks(env: int) -> Any:
    from fmpy.fmi2 import (  # type: ignore[attr-defined]
        calloc,
        fmi2CallbackAllocateMemoryTYPE,
        fmi2CallbackFreeMemoryTYPE,
        fmi2CallbackFunctions,
        fmi2CallbackLoggerTYPE,
        free,
    )
    from fmpy.logging import addLoggerProxy

    if not _callbacks_kept:
        _callbacks_kept.append(fmi2CallbackLoggerTYPE(_route))
        _callbacks_kept.append(fmi2CallbackAllocateMemoryTYPE(calloc))
        _callbacks_kept.append(fmi2CallbackFreeMemoryTYPE(free))
    callbacks = fmi2CallbackFunctions()
    callbacks.logger, callbacks.allocateMemory, callbacks.freeMemory = _callbacks_kept
    callbacks.componentEnvironment = env
    addLoggerProxy(ctypes.byref(callbacks))  # formats the FMU's printf-style messages
    return callbacks


_next_env = iter(range(1, 1 << 62))


class FmuInstance:
    """One instance of an :class:`FmuModel` (FMPy's ``FMU2Slave``), its log kept apart from
    other instances' (FMPy's log proxy is one per process; the instance's environment pointer
    routes each message). Low level: :class:`plant_sim.fmu.FmuPlant` is the axis."""

    def __init__(self, model: FmuModel, name: str) -> None:
        from fmpy.fmi2 import FMU2Slave

        self.model = model
        self.env = next(_next_env)
        self.log: list[str] = []
        with _LOG_LOCK:
            _LOGS[self.env] = self.log
        self._slave = FMU2Slave(
            guid=model.guid,
            unzipDirectory=str(model.unzip_dir),
            modelIdentifier=model.model_identifier,
            instanceName=name,
        )
        self._callbacks = _callbacks(self.env)
        self._instantiated = False
        self._freed = False
        with self.failure("fmi2Instantiate"):
            self._slave.instantiate(callbacks=self._callbacks, loggingOn=False)
        self._instantiated = True

    @property
    def component(self) -> Any:
        return self._slave.component

    def function(self, name: str) -> Any:
        """The FMI function itself (argument types set), for a caller that steps it every
        cycle without FMPy's per-call conversions."""
        return self._slave._functions[name]

    @contextlib.contextmanager
    def failure(self, call: str) -> Iterator[None]:
        """FMPy's exception of ``call`` as :class:`FmuStepError` with the FMU's messages."""
        try:
            yield
        except FmuStepError:
            raise
        except Exception as exc:
            messages = tuple(self.log)
            said = "; ".join(messages) if messages else str(exc)
            raise FmuStepError(
                f"FMU {self.model.describe()}: {call} failed: {said}",
                call=call,
                messages=messages,
            ) from None

    def setup(self, initial_position: float | None) -> None:
        model, slave = self.model, self._slave
        try:
            with self.failure("fmi2SetupExperiment"):
                slave.setupExperiment(startTime=0.0)
            for p in model.parameters:
                with self.failure(f"fmi2Set{p.type} {p.name}"):
                    if p.type == "Real":
                        slave.setReal([p.reference], [float(p.value)])
                    elif p.type == "Integer":
                        slave.setInteger([p.reference], [int(p.value)])
                    else:
                        slave.setBoolean([p.reference], [bool(p.value)])
            if initial_position is not None:
                if model.initial_position is None:
                    if initial_position != 0.0:
                        raise FmuError(
                            f"FMU {model.describe()}: the axis must start at "
                            f"{initial_position:g}, and the FMU has no initial-position "
                            "parameter (map one: FmuMapping.initial_position)"
                        )
                else:
                    with self.failure("fmi2SetReal initial position"):
                        slave.setReal([model.initial_position], [float(initial_position)])
            with self.failure("fmi2EnterInitializationMode"):
                slave.enterInitializationMode()
            with self.failure("fmi2ExitInitializationMode"):
                slave.exitInitializationMode()
        except FmuStepError as exc:  # before the run: the FMU is refused, as a bad file is
            raise FmuError(str(exc)) from None

    def get_real(self, references: list[int]) -> list[float]:
        with self.failure("fmi2GetReal"):
            return list(self._slave.getReal(references))

    def free(self) -> None:
        """Terminate and free the instance (FMPy also releases the library handle)."""
        if self._freed:
            return
        self._freed = True
        try:
            if self._instantiated:
                with contextlib.suppress(Exception):
                    self._slave.terminate()
                with contextlib.suppress(Exception):
                    self._slave.freeInstance()
        finally:
            with _LOG_LOCK:
                _LOGS.pop(self.env, None)


_MODELS: dict[tuple[Any, ...], FmuModel] = {}
_MODELS_LOCK = threading.Lock()


def load_fmu(
    spec: FmuSpec | str | Path, parameters: Mapping[str, object] | None = None
) -> FmuModel:
    """A checked :class:`FmuModel` (module docstring); one per spec and file state per process."""
    if not isinstance(spec, FmuSpec):
        spec = FmuSpec(Path(spec))
    if parameters:
        spec = spec.with_parameters(**{k: v for k, v in parameters.items()})
    try:
        stat = spec.path.stat()
        key: tuple[Any, ...] = (
            spec.path.resolve(),
            stat.st_mtime_ns,
            stat.st_size,
            spec.parameters,
            repr(spec.mapping),
        )
    except OSError:
        key = ()
    with _MODELS_LOCK:
        model = _MODELS.get(key) if key else None
    if model is None:
        model = FmuModel(spec)
        if key:
            with _MODELS_LOCK:
                _MODELS[key] = model
    return model
