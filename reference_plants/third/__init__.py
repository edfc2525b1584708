"""A third test plant, written from the physics apart from ``plant_sim/physics/kernel.py`` and from
``reference_plants/independent`` (neither imported nor copied), with modelling choices neither
shares:

======================  ===================  =====================  =========================
aspect                  kernel               independent plant      third plant
======================  ===================  =====================  =========================
drive train             two masses           two masses             three masses: motor,
                                                                    torsional coupling, screw,
                                                                    nut, load
friction                set-valued Coulomb   tanh-smoothed          LuGre: bristle state,
                        (Karnopp)            Coulomb + Stribeck     pre-sliding hysteresis
integrator              leapfrog             RK4                    symplectic Euler + exact
                                                                    exponential for bristles
current loop            first-order lag      sampled PI on R-L      sampled PI on R-L with
                                                                    back-EMF, voltage limit,
                                                                    PWM delay
anti-windup             clamping             conditional            back-calculation
speed measurement       true angle           quantised encoder      sin/cos encoder with
                                                                    interpolation error
torque trace            instantaneous        current sample         anti-alias filtered
dead time               torque path          torque path            speed set-point path
timing                  125 µs / 1 ms        125 µs / 1 ms          250 µs or 125 µs / 1 ms,
                                                                    current loop 62.5 µs
recorded every          2 ms                 2 ms                   1 ms
excitation              jerk-limited moves   the same               NC program: rapids
                                                                    without jerk limit, feeds,
                                                                    arcs, creep feeds
process load            2 Hz Butterworth     Ornstein–Uhlenbeck     random steps + cable chain
families                mill, slide          mill, slide            rotary table, vertical Z
======================  ===================  =====================  =========================

Its test set for the concealed-effect matrix is :mod:`diagnosis.testsets.third`
(``python -m diagnosis matrix --plant third``). The axis-file format is shared
(:func:`.plant.axis_of` writes what a user would).
"""

from .plant import Physics, axis_of, simulate

__all__ = ["Physics", "axis_of", "simulate"]
