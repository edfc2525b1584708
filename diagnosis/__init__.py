"""Model-vs-recording diagnosis: where an axis file and a recording differ, which physics of
the axis-file table the model leaves out, the fitted model and the proof on held-out data.

Modules, by stage: :mod:`.replay` (closed-loop simulation like a recording),
:mod:`.measured` (the measured motion on a uniform grid), :mod:`.evidence` (scales of a
recording), :mod:`.metrics` (NRMSE, fit %, autocorrelation time, held-out improvement test),
:mod:`.mismatch` (operating conditions, mismatch windows, residual tests); :mod:`.effects`
(the registry: one class per effect with its keys, presence, strip, the axis-file values of an
estimate, absent values, description, its column word, how the evidence tests it; the
experiments that tell two apart), :mod:`.parameters` (bounds, data-sheet uncertainty, units,
suspects); evidence (stage 1): :mod:`.screen` with the regressors of :mod:`.idim` (torque
balance), :mod:`.deflection` (two measuring systems) and :mod:`.loop_tests` (the control
path), :mod:`.regression` and :mod:`.randomization` (the tests); closed loop (stage 2):
:mod:`.closed_loop`, :mod:`.fit` (bounded multi-start simulation-error fitting),
:mod:`.scoring` (held-out blocks, the decision's test); :mod:`.engine` (:func:`diagnose`),
:mod:`.stages` (their state), :mod:`.adequacy` and :mod:`.unexplained` (what the model class
still misses); :mod:`.outcome` and :mod:`.results` (what it returns), :mod:`.explain`,
:mod:`.summary`, :mod:`.quantity` (the words and units), :mod:`.report`,
:mod:`.report_html`, :mod:`.report_figures` (the report files); :mod:`.synthetic` and
:mod:`.testsets` (the concealed test sets), :mod:`.matrix` (confusion matrix),
:mod:`.timing` (its benchmark); :mod:`.commands` (``python -m diagnosis``).
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
