"""The simulator: a servo axis and a CiA 402 drive that do not exist, and the tools that hold
models of real axes against recordings.

Sub-packages, each with one job:

* ``physics``: the axis as physics (two-mass elastic axis, ball screw, backlash, friction, PI
  speed loop, feed-forward) in a compiled numba kernel, closed-loop simulation and an
  independent ``solve_ivp`` reference;
* ``paper``: the paper's section X reproduced offline (Fig. 8, 9, summary);
* ``drive``: the simulated CiA 402 drive on a CAN bus (in process or as its own process);
* ``identification``: section IX's identification (mass, friction; Nelder-Mead);
* ``datasets``: public recordings of real machines (EMPS, BAM's XL330) as trace files;
* ``diagnosis``: where a recording and its model differ, and what physics the model left out;
* ``fleet``: condition monitoring of many axes' recordings (vibration episodes, backlash
  trends) on Dask;
* ``commands``: ``python -m plant_sim COMMAND`` (console script ``backlash-sim``).

The file formats it reads and writes (axis file, trace file) are the whole project's:
:mod:`virtual_bus.formats`.
"""
