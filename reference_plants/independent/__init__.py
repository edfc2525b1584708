"""An independent test plant: the servo axis of an axis file, written apart from
``plant_sim/physics/kernel.py`` (neither imported nor copied) with other modelling choices:

======================  =============================================  ==========================
aspect                  plant_sim kernel                               independent plant
======================  =============================================  ==========================
integrator              staggered leapfrog, substeps per speed cycle   classic RK4, step from the
                                                                       fastest rate (h·λ <= 0.4)
friction                set-valued Coulomb/Stribeck (Karnopp, stops)   tanh-smoothed Coulomb +
                                                                       Stribeck, no stiction
backlash contact        clamped spring-damper at the flank             spring + damper engaging
                                                                       with penetration (tanh),
                                                                       Hunt–Crossley-like
current loop            exact first-order lag                          sampled PI current loop
                                                                       on an R-L winding
speed measurement       true-angle backward difference                 quantised encoder (2^20),
                                                                       backward difference, 1st-
                                                                       order filter (50 µs)
anti-windup             clamping                                       conditional integration
dead time               whole speed cycles                             whole current-loop cycles
sensors                 exact                                          quantised motor encoder
                                                                       and load scale (5 nm)
sensor time offset      history per speed cycle                        history per current cycle
======================  =============================================  ==========================

:mod:`diagnosis.testsets.independent` turns it into noisy recordings with coloured noise for
the concealed-effect matrix. Trace files are written with
:class:`virtual_bus.formats.trace.Trace` (the FILE format only).
"""

from reference_plants.independent.plant import (
    COLUMNS,
    PlantOptions,
    SteppedPlant,
    parameters,
    simulate,
)

__all__ = ["COLUMNS", "PlantOptions", "SteppedPlant", "parameters", "simulate"]
