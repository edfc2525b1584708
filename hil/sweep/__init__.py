"""Sweeps over many axes of an FMU family on Dask (``python -m hil sweep``): the success
rates of the commissioning and diagnosis procedures on axes this project did not write
(docs/fmu.md, "Sweeps").

* :mod:`.runner` -- seeds, resumable Parquet parts, the table and its summary;
* :mod:`.tasks` -- what runs per axis (:data:`~.tasks.TASKS`).
"""
