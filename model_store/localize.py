"""Fetch a run's user files from the store so that any process, on any machine, builds the same env."""

from __future__ import annotations

from pathlib import Path

from common.config import EnvConfig, RunConfig
from model_store.runs import RunStore


def localize_env(run: RunConfig, runs: RunStore, folder: Path, track: str | None = None) -> EnvConfig:
    """The run's env config, with its stored reward function and action space written into ``folder``
    and used instead of the paths the run was started with; ``track`` overrides the track."""
    env = run.env
    for name, attr in (("reward_function.py", "reward_fn"), ("model_metadata.json", "action_space")):
        path = folder / name
        path.write_bytes(runs.read_file(run.run_id, name))
        env = env.model_copy(update={attr: str(path)})
    return env.model_copy(update={"track": track}) if track else env
