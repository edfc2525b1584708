"""Plants written apart from the simulator's kernel (:mod:`plant_sim.physics.kernel`), neither
importing nor copying it, with other modelling choices: the second and third implementations the
proofs and the diagnosis's concealed-effect matrix run on (docs/diagnosis.md).

* :mod:`.independent` -- RK4, smoothed friction, damped contact, a sampled PI current loop,
  quantised sensors;
* :mod:`.third` -- three masses, LuGre friction, a PI current loop with back-EMF and a voltage
  limit, a sin/cos encoder, the dead time in the speed set-point path.

They read the project's axis-file format and write its trace format, nothing else of it.
"""
