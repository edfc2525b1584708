"""Model-vs-recording diagnosis: where an axis file and a recording differ, which physics of
the axis-file table the model leaves out, the fitted model and the proof on held-out data.

Modules: :mod:`.replay` (closed-loop simulation like a recording), :mod:`.metrics` (NRMSE,
fit %, autocorrelation time, held-out improvement test), :mod:`.mismatch` (operating
conditions, mismatch windows, residual tests), :mod:`.effects` (one class per effect: keys,
presence, strip, candidate, description), :mod:`.parameters` (bounds, data-sheet
uncertainty, units, suspects), :mod:`.evidence` (scales and residual features of a
recording), :mod:`.fit` (bounded multi-start simulation-error fitting), :mod:`.scoring`
(held-out blocks, weights, the decision's test), :mod:`.engine` (:func:`diagnose`, in
stages; :mod:`.stages` their state, :mod:`.selection` the forward selection),
:mod:`.adequacy` (does the model class explain the recording), :mod:`.results` (what it
returns), :mod:`.explain` (the paragraph), :mod:`.report` (report files), :mod:`.synthetic`
(the concealed test set), :mod:`.matrix` (confusion matrix), :mod:`.bench`.
See docs/diagnosis.md.

>>> from diagnosis import diagnose, write_report
>>> d = diagnose(read_trace("rec.csv"), load_axis("axis.toml"))
>>> d.left_out, d.fit_after["motor_torque"].fit_percent
"""

from .effects import Effect
from .engine import DiagnosisOptions, diagnose
from .errors import DiagnosisInputError, DiagnosisOptionError
from .outcome import Diagnosis
from .replay import simulate_like
from .report import write_report

__all__ = [
    "Diagnosis",
    "DiagnosisInputError",
    "DiagnosisOptionError",
    "DiagnosisOptions",
    "Effect",
    "diagnose",
    "simulate_like",
    "write_report",
]
