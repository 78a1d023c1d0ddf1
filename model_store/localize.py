"""Fetch a run's user files from the store so that any process, on any machine, builds the same env."""

from __future__ import annotations

from pathlib import Path

from common.config import EnvConfig, RunConfig
from model_store.runs import RunStore


def localize_env(run: RunConfig, runs: RunStore, folder: Path, worker: int | None = None) -> EnvConfig:
    """The run's env config (rollout worker ``worker``'s own, ``RunConfig.worker_env``, when given), with its stored
    reward function and action space written into ``folder`` and used instead of the paths the run was started
    with."""
    env = run.env if worker is None else run.worker_env(worker)
    for name, attr in (("reward_function.py", "reward_fn"), ("model_metadata.json", "action_space")):
        path = folder / name
        path.write_bytes(runs.read_file(run.run_id, name))
        env = env.model_copy(update={attr: str(path)})
    return env
