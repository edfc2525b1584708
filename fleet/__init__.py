"""Condition monitoring of a fleet of servo axes (paper section XI, Fig. 4).

The paper's conclusion: knowing when an axis vibrates and at what frequency "is significantly
helpful for condition monitoring and preventive maintenance". This package reads routine
recordings of many axes (trace files and candump logs of the bridge's bus), finds the
vibration episodes with the paper's detector (Fig. 5) run offline, gives each its eq. 13
band verdict, estimates the lost motion at reversals where both measuring systems are
recorded, and follows both over the recordings' dates per axis.

Modules, one job each:

- :mod:`.sources`:   which files, and which machine / axis / date each belongs to
- :mod:`.readers`:   a recording as a stream of fixed-size chunks (trace CSV, candump log)
- :mod:`.episodes`:  the detector of Fig. 5 over a chunk stream -> vibration episodes
- :mod:`.lost_motion`: lost motion at reversals from the two measuring systems
- :mod:`.analyse`:   one recording -> one :class:`~.analyse.RecordingResult` (a Dask task)
- :mod:`.fleet`:     tables, trends, ranking across the fleet
- :mod:`.figures`:   Fig. 4 of the fleet, trend plots, the HTML index
- :mod:`.runner`:    runs the per-recording tasks on Dask (local processes or a cluster)
- :mod:`.demo_fleet`: a simulated fleet with a known truth, for tests and ``--demo``
"""
