"""The paper's beta_T procedure, automated (section VIII): pure, shared by every runner.

"This threshold should be defined experimentally by starting from small values for stability,
and it is increased to improve the response." Here, for any runner that can play a test
motion and record it (the simulated axis offline, the bridge over the bus):

1. **provoke** (:mod:`.ladder`): the reference trial, the regulator off (ordinary control,
   Fig. 1), is played with test motions of rising severity -- the user's own, the default
   motion adapted to k_v and 2008h (:mod:`.motion`), a sharp deceleration into the gap sized by
   the measured torque, a creep feed, a reversal, a load pulse where the runner offers one --
   within the travel and the torque limit, until one limit-cycles; the first that does is the
   test motion, and a refusal names every motion tried and what it showed;
2. **trials** (:mod:`.search`) from a small beta_T upwards by a factor (by default from the
   limit cycle's own beta level / 64 to x 16), each judged by what the axis does
   (:mod:`.judge`): VIBRATING when the following error oscillates in eq. 13's band above a
   share of the reference's limit cycle, INEXACT when it is quiet but has not reached its
   standstill accuracy by the end of the dwell (the bounded wait; lambda's recovery is reported,
   never judged), STOPPED on any stop reason, else STABLE;
3. the search **stops at the first vibration** and backs off by ``margin``: the result is the
   largest stable beta_T divided by the margin, but never below the smallest beta_T of the
   quiet-and-exact range it was found in (a smaller one would cost exactness: the paper's
   "stability with the cost of some following error"), confirmed by one more trial that must be
   STABLE; the result says what it costs in following error.

It never stores anything itself: the runner writes the result (2002h, 1010h) only when the
outcome is FOUND, and stops the axis with the reason otherwise.
"""

from ..errors import TuningError, TuningInputError
from .judge import (
    Limits,
    Metrics,
    Record,
    SafetyLimits,
    TrialResult,
    Verdict,
    band_amplitude,
    judge,
    measure,
    safety_stop,
)
from .ladder import Ladder, Rung, TorqueModel
from .motion import (
    DWELL_TIMES_TV,
    STANDSTILL_AVERAGE_S,
    WATCH_TIMES_TV,
    MotionProfile,
    TuningMotion,
    motion_from_samples,
)
from .search import Outcome, Runner, SearchConfig, SearchResult, Tried, search

__all__ = [
    "DWELL_TIMES_TV",
    "STANDSTILL_AVERAGE_S",
    "WATCH_TIMES_TV",
    "Ladder",
    "Limits",
    "Metrics",
    "MotionProfile",
    "Outcome",
    "Record",
    "Rung",
    "Runner",
    "SafetyLimits",
    "SearchConfig",
    "SearchResult",
    "TorqueModel",
    "TrialResult",
    "Tried",
    "TuningError",
    "TuningInputError",
    "TuningMotion",
    "Verdict",
    "band_amplitude",
    "judge",
    "measure",
    "motion_from_samples",
    "safety_stop",
    "search",
]
