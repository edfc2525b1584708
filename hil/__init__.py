"""The bridge and the simulated drive together: hardware-in-the-loop without hardware.

What joins :mod:`bridge` (the regulator as a CANopen node) and :mod:`plant_sim` (the
simulated CiA 402 drive and the axis physics) lives here, above both: the in-process
harness (``harness``), the main job (``demo``: section X over the bus), the benchmarks of
the loop (``bench``, ``bench_realtime``) and the offline commissioning on the simulated axis
(``offline``, ``loop``: ``tune``, the paper's beta_T procedure, and ``freqresp``, Fig. 2, on
any steppable plant). ``python -m hil COMMAND``.
"""
