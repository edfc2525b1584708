"""The paper's section X reproduced offline: the scenario (``scenarios``) and its metrics,
figures and summary (``outputs``), shared by ``plant_sim paper`` and ``hil demo``."""
