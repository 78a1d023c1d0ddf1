"""racer's simulator: DeepRacer tracks, the MuJoCo car and world, the camera and the gymnasium env.

The model (``world``, ``physics``, ``actuation``), the task (``task``), the reward-function API (``reward``), the
env that wires them (``env``), tracks, texture and camera (``track``, ``texture``, ``camera``), what a held-out
condition does to the frames (``conditions``), the parts of
``racer limit`` (``car_limits``, ``raceline``, ``follower``) and of ``racer calibrate`` (``calibration``).
Importing ``sim`` registers ``Racer-v0`` with gymnasium, so ``gymnasium.make("sim:Racer-v0")`` works.
See ARCHITECTURE.md.
"""

from sim._gl import ensure_gl_backend

ensure_gl_backend()  # before mujoco is imported anywhere


def register_envs() -> None:
    """Register ``Racer-v0`` with gymnasium (idempotent)."""
    import gymnasium

    if "Racer-v0" not in gymnasium.registry:
        gymnasium.register(id="Racer-v0", entry_point="sim.env:RacerEnv")


register_envs()
