"""A random-policy drive: the simulator's smoke test and the README's first command."""

from __future__ import annotations

from common.config import EnvConfig
from sim.env import RacerEnv


def drive_random(config: EnvConfig, episodes: int, seed: int = 0) -> list[dict]:
    """Drive ``episodes`` episodes with uniformly random actions; one summary dict per episode."""
    env = RacerEnv(config=config)
    env.action_space.seed(seed)
    rows = []
    for ep in range(episodes):
        env.reset(seed=seed + ep)
        total, done, info = 0.0, False, {}
        while not done:
            _, reward, term, trunc, info = env.step(env.action_space.sample())
            total += reward
            done = term or trunc
        p = info["params"]
        rows.append(
            {
                "episode": ep,
                "steps": info["steps"],
                "status": info["episode_status"],
                "progress": p["progress"],
                "return": total,
            }
        )
    env.close()
    return rows
