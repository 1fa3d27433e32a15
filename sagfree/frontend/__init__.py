"""The front end over every solver, above our method and the baselines (DESIGN section 2): the solver
table (``table``), options checked once (``options``), ``solve`` for one strand, ``optimize`` and the
forward check for many on all cores or a Dask cluster (``batch``, ``cluster``), and the checkpoints of
long batches (``checkpoint``)."""
