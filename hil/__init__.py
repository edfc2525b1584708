"""The bridge and the simulated drive together: hardware-in-the-loop without hardware.

What joins :mod:`bridge` (the regulator as a CANopen node) and :mod:`plant_sim` (the simulated
CiA 402 drive and the axis physics) lives here, above both. ``python -m hil COMMAND``. On
this branch: the offline commissioning on the simulated axis -- ``hil tune`` (the paper's
beta_T procedure, section VIII) and ``hil freqresp`` (Fig. 2) -- with the loop of
:mod:`hil.loop` (any steppable plant: the compiled kernel's :class:`plant_sim.model.AxisPlant`,
the tests' independent plant).
"""
