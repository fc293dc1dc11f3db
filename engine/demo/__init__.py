"""A plant run on this one machine: ``plantkg demo`` (``run``), the simulated sources it feeds
(``simulate``, ``simulate_ngsi``) and the same from Python (``local_plant``, for notebooks)."""
