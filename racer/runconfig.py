"""Turn ``racer train`` / ``racer trainer`` options into a RunConfig and the run's files."""

from __future__ import annotations

import re
from pathlib import Path

from common.action_space import ActionSpace, default_action_space, load_action_space
from common.car_calibration import CarCalibration, load_car
from common.config import (
    EnvConfig,
    PolicyConfig,
    PretrainedError,
    RandomizationConfig,
    RunConfig,
    network_from_metadata,
)
from common.hyperparams import Hyperparameters, load_hyperparameters
from common.jsonfile import load_json_model
from model_store import RunStore, StoreError
from sim.env import preflight_reward
from sim.reward import example_path
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
    notes: list[str] | None = None,
    randomization_update: dict | None = None,
) -> tuple[RunConfig, dict[str, bytes]]:
    """Validate the user's files now (before any process starts) and build the run's config and files.

    ``notes`` (if given) collects one line per thing in the files that racer accepts but does not use;
    ``randomization_update`` sets RandomizationConfig fields (from a DRfC run.env).
    """
    load_track(track)
    for t in worker_tracks or []:
        load_track(t)
    reward_path = Path(reward_fn) if reward_fn else example_path("default")
    actions = load_action_space(action_space) if action_space else default_action_space()
    hp = load_hyperparameters(hyperparams) if hyperparams else Hyperparameters()
    if notes is not None and hp.ignored():
        notes.append(f"{hyperparams}: accepted, not used by racer: {', '.join(hp.ignored())}")
    dr = load_randomization(randomization) if randomization else None
    car = load_car(car_calibration) if car_calibration else CarCalibration()
    dr = (dr or RandomizationConfig()).model_copy(update=randomization_update or {})
    env = EnvConfig(track=track, randomization=RandomizationConfig.model_validate(dr.model_dump()), car=car)
    # A broken reward function fails here, naming the user's file, before any process starts. The check drives a
    # throwaway env (its own copy of the reward module) on the run's track, so nothing it caches reaches training.
    preflight_reward(env.model_copy(update={"reward_fn": str(reward_path), "action_space": action_space}))
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


def check_pretrained(runs: RunStore, run: RunConfig, files: dict[str, bytes], ref: str) -> RunConfig:
    """``run`` set to start from ``ref`` (``RUN[:best|latest|N]``, default latest) of another run in ``runs``.

    Refused in one line when the source or its checkpoint is missing, its action space differs (DeepRacer's clone
    keeps the action space) or its network or frame stack differs (the weights would not fit).
    """
    source, _, which = ref.partition(":")
    which = which or "latest"
    try:
        version = runs.resolve(source, which)
        runs.checkpoint_meta(source, version)
        theirs = RunConfig.model_validate_json(runs.read_file(source, "config.json"))
        their_actions = ActionSpace.model_validate_json(runs.read_file(source, "model_metadata.json"))
    except (StoreError, ValueError) as exc:
        raise PretrainedError(f"pretrained {ref!r}: {str(exc).splitlines()[0]}") from None
    ours = ActionSpace.model_validate_json(files["model_metadata.json"])
    if their_actions.model_dump(include={"action_space_type", "action_space"}) != ours.model_dump(
        include={"action_space_type", "action_space"}
    ):
        raise PretrainedError(
            f"pretrained {ref!r}: its action space differs from this run's model_metadata.json; "
            "a pretrained model keeps its action space"
        )
    mine = run.policy.model_dump(exclude={"l2"})
    if theirs.policy.model_dump(exclude={"l2"}) != mine:
        raise PretrainedError(
            f"pretrained {ref!r}: its network {theirs.policy.model_dump()} differs from this run's {mine}"
        )
    return run.model_copy(update={"pretrained": f"{source}:{version}"})
