"""racer.common: what the roles share (of these modules only ``policy`` imports torch).

Run configuration (``config``), DeepRacer's files (``action_space``, ``hyperparams``), the car file
(``car_calibration``), Redis key names (``keys``), the worker → trainer wire format (``protocol``), Redis
connections and outage retries (``redis_util``, ``retry``), the actor-critic network and checkpoint bytes
(``policy``), the frame stack (``framestack``) and DeepRacer sim-traces (``simtrace``). See ARCHITECTURE.md.
"""
