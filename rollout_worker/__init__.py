"""racer.rollout_worker: the rollout worker role (``racer worker``).

``worker`` builds the run's env and network from the store, acts with the newest published policy, pushes
segments of experience and heartbeats to Redis, and uploads DeepRacer sim-traces per iteration. See
ARCHITECTURE.md.
"""
