"""The tasks a sweep runs per axis (:mod:`.base` says what a task is), registered by name in
:data:`TASKS`: one module each; a new task is a module here and its name in :data:`MODULES`."""

from __future__ import annotations

import importlib

from .base import Row, Task

#: The task modules of this package, in the order ``--help`` lists them.
MODULES = ("limit_cycle", "tune", "circular", "diagnose", "freqresp")

TASKS: dict[str, Task] = {}
for _name in MODULES:
    _task: Task = importlib.import_module(f"{__name__}.{_name}").TASK
    TASKS[_task.name] = _task

__all__ = ["TASKS", "Row", "Task"]
