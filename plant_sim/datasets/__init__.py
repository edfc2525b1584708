"""Public recordings of real machines as trace files: EMPS (``emps``, with the data set's
relative force error, ``force_error``) and BAM's XL330 pendulum (``xl330``)."""
