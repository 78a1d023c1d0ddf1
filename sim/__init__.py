"""racer's simulator: DeepRacer tracks, the MuJoCo car and world, the camera and the gymnasium env.

Importing ``sim`` registers ``Racer-v0`` with gymnasium, so ``gymnasium.make("sim:Racer-v0")`` works.
"""

from sim._gl import ensure_gl_backend

ensure_gl_backend()  # before mujoco is imported anywhere


def register_envs() -> None:
    """Register ``Racer-v0`` with gymnasium (idempotent)."""
    import gymnasium

    if "Racer-v0" not in gymnasium.registry:
        gymnasium.register(id="Racer-v0", entry_point="sim.env:RacerEnv")


register_envs()
