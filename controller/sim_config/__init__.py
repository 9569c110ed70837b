"""The simulator's configuration language: the ``[sim]`` sections (``sections.py``) and the fault and
quirk specs they hold (``fault_specs.py``, ``quirk_specs.py``). Read with the rest of the configuration
file by ``controller/config.py``, so that a bad entry is refused by any process that reads it; the
simulated devices that act on them are in sim_backend/."""
