"""Turn ``racer train`` / ``racer trainer`` options into a RunConfig and the run's files."""

from __future__ import annotations

import re
from pathlib import Path

from common.action_space import default_action_space, load_action_space
from common.car_calibration import CarCalibration, load_calibration
from common.config import EnvConfig, PolicyConfig, RandomizationConfig, RunConfig, network_from_metadata
from common.hyperparams import Hyperparameters, load_hyperparameters
from common.jsonfile import load_json_model
from sim.reward import check_reward_function, example_path, load_reward_function
from sim.track import load_track

_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([smh]?)\s*$")


def parse_duration(text: str) -> float:
    """Seconds in ``90s``, ``5m``, ``1.5h`` or a bare number of seconds; ValueError naming the text otherwise."""
    m = _DURATION.match(text)
    if not m:
        raise ValueError(f"duration {text!r} is not valid: use a number with s, m or h (90s, 5m, 2h)")
    return float(m.group(1)) * {"": 1, "s": 1, "m": 60, "h": 3600}[m.group(2)]


def build_run(
    run_id: str,
    track: str = "reinvent_base",
    reward_fn: str | None = None,
    action_space: str | None = None,
    hyperparams: str | None = None,
    randomization: str | None = None,
    worker_tracks: list[str] | None = None,
    seed: int = 0,
    car_calibration: str | None = None,
) -> tuple[RunConfig, dict[str, bytes]]:
    """Validate the user's files now (before any process starts) and build the run's config and files."""
    load_track(track)
    for t in worker_tracks or []:
        load_track(t)
    reward_path = Path(reward_fn) if reward_fn else example_path("default")
    # A broken reward function fails here, naming the user's file, before any process starts.
    check_reward_function(load_reward_function(reward_path))
    actions = load_action_space(action_space) if action_space else default_action_space()
    hp = load_hyperparameters(hyperparams) if hyperparams else Hyperparameters()
    dr = load_randomization(randomization) if randomization else None
    car = load_calibration(car_calibration) if car_calibration else CarCalibration()
    env = EnvConfig(track=track, randomization=dr or RandomizationConfig(), car=car)
    policy = PolicyConfig(network=network_from_metadata(actions.neural_network), stack_size=hp.stack_size)
    run = RunConfig(run_id=run_id, env=env, hyperparams=hp, policy=policy, worker_tracks=worker_tracks or [], seed=seed)
    files = {
        "reward_function.py": reward_path.read_bytes(),
        "model_metadata.json": actions.to_json().encode(),
        "hyperparameters.json": hp.to_json().encode(),
    }
    return run, files


class RandomizationFileError(ValueError):
    """A domain-randomization settings file that cannot be used; the message names the file."""


def load_randomization(path: str | Path) -> RandomizationConfig:
    """Read a randomization JSON file; RandomizationFileError naming the file and the bad field."""
    return load_json_model(path, "randomization file", RandomizationConfig, RandomizationFileError)
