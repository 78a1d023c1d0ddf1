"""Turn ``racer train`` / ``racer trainer`` options into a RunConfig and the run's files."""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
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
from common.defaults import DEFAULT_TRACK
from common.errors import OptionError, UserError
from common.hyperparams import Hyperparameters, HyperparametersError, load_hyperparameters
from common.jsonfile import load_json_model
from common.race import RaceConfig, RaceType
from model_store import RunStore, StoreError
from sim.env import preflight_reward
from sim.reward import example_path
from sim.track import load_track

_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([smh]?)\s*$")


def parse_duration(text: str) -> float:
    """Seconds in ``90s``, ``5m``, ``1.5h`` or a bare number of seconds; OptionError naming the text otherwise."""
    m = _DURATION.match(text)
    if not m:
        raise OptionError(f"duration {text!r} is not valid: use a number with s, m or h (90s, 5m, 2h)")
    return float(m.group(1)) * {"": 1, "s": 1, "m": 60, "h": 3600}[m.group(2)]


def build_run(
    run_id: str,
    track: str = DEFAULT_TRACK,
    reward_fn: str | None = None,
    action_space: str | None = None,
    hyperparams: str | None = None,
    randomization: str | None = None,
    worker_tracks: list[str] | None = None,
    seed: int = 0,
    car_calibration: str | None = None,
    notes: list[str] | None = None,
    randomization_update: dict | None = None,
    race: RaceConfig | None = None,
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
    env = EnvConfig(
        track=track,
        randomization=RandomizationConfig.model_validate(dr.model_dump()),
        car=car,
        race=race or RaceConfig(),
    )
    # A broken reward function fails here, naming the user's file, before any process starts. The check drives a
    # throwaway env (its own copy of the reward module) on the run's track, so nothing it caches reaches training.
    preflight_reward(env.model_copy(update={"reward_fn": str(reward_path), "action_space": action_space}))
    if hp.greedy_action != "mean" and actions.discrete:
        # Nothing is accepted that racer cannot honour: a discrete policy acts greedily by its argmax.
        raise HyperparametersError(
            f"{hyperparams}: greedy_action {hp.greedy_action!r} applies to a continuous action space; "
            f"{action_space or 'the default action space'} is discrete"
        )
    policy = PolicyConfig(
        network=network_from_metadata(actions.neural_network), stack_size=hp.stack_size, greedy_action=hp.greedy_action
    )
    run = RunConfig(run_id=run_id, env=env, hyperparams=hp, policy=policy, worker_tracks=worker_tracks or [], seed=seed)
    files = {
        "reward_function.py": reward_path.read_bytes(),
        "model_metadata.json": actions.to_json().encode(),
        "hyperparameters.json": hp.to_json().encode(),
    }
    return run, files


class RandomizationFileError(UserError, ValueError):
    """A domain-randomization settings file that cannot be used; the message names the file."""


def load_randomization(path: str | Path) -> RandomizationConfig:
    """Read a randomization JSON file; RandomizationFileError naming the file and the bad field."""
    return load_json_model(path, "randomization file", RandomizationConfig, RandomizationFileError)


class RaceFileError(UserError, ValueError):
    """A race settings file that cannot be used; the message names the file and the bad field."""


def load_race(path: str | Path | None, race_type: str | None = None) -> RaceConfig | None:
    """The race of ``--race FILE`` (a JSON of ``common/race.py: RaceConfig``) with ``--race-type`` set on top;
    None when neither is given. An unknown race type is an OptionError naming the value."""
    if path is None and race_type is None:
        return None
    race = load_json_model(path, "race file", RaceConfig, RaceFileError) if path else RaceConfig()
    if race_type is not None:
        names = [t.value for t in RaceType]
        if race_type.upper() not in names:
            raise OptionError(f"--race-type {race_type!r} is not one of {', '.join(names)}")
        race = race.model_copy(update={"race_type": RaceType(race_type.upper())})
    return race


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
        theirs = runs.read_config(source)
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
    if sorted(their_actions.sensor) != sorted(ours.sensor):
        raise PretrainedError(
            f"pretrained {ref!r}: its sensors {their_actions.sensor} differ from this run's {ours.sensor}; "
            "the network's inputs would not fit"
        )
    # The weight decay and the greedy action are not part of the network: a pretrained model takes the run's own.
    mine = run.policy.model_dump(exclude={"l2", "greedy_action"})
    if theirs.policy.model_dump(exclude={"l2", "greedy_action"}) != mine:
        raise PretrainedError(
            f"pretrained {ref!r}: its network {theirs.policy.model_dump()} differs from this run's {mine}"
        )
    return run.model_copy(update={"pretrained": f"{source}:{version}"})


@dataclass
class NewRun:
    """What defines a new run: ``racer train``'s (or ``racer trainer``'s) options, merged with a DRfC folder."""

    track: str = DEFAULT_TRACK
    reward_fn: str | None = None
    action_space: str | None = None
    hyperparams: str | None = None
    randomization: str | None = None
    """A randomization JSON file."""
    randomization_update: dict = field(default_factory=dict)
    """RandomizationConfig fields set on top (from a DRfC run.env)."""
    worker_tracks: list[str] = field(default_factory=list)
    seed: int = 0
    car: str | None = None
    """A car preset's name or a car.json (None: the default car)."""
    max_policy_lag: int = 0
    segment_steps: int = 32
    pretrained: str | None = None
    """``RUN[:best|latest|N]`` of another run in the store to start from."""
    race: RaceConfig | None = None
    """The race (``--race``/``--race-type`` or a DRfC run.env); None: a time trial."""


def open_run(runs: RunStore, run_id: str, new: NewRun | None) -> tuple[RunConfig, dict[str, bytes], list[str]]:
    """The run to train: with ``new`` None (a resume) the stored one; else a new run built from the user's files,
    checked now, and refused if ``run_id`` already has checkpoints. Returns its config, its files (none on a
    resume) and one note per thing in the files that racer accepts but does not use."""
    if new is None:
        return runs.read_config(run_id), {}, []
    if runs.newest_whole(run_id) is not None:
        raise OptionError(
            f"run {run_id!r} already exists in {runs.store.uri}: add --resume to continue it, "
            "or choose another --run-id"
        )
    notes: list[str] = []
    run, files = build_run(
        run_id,
        new.track,
        new.reward_fn,
        new.action_space,
        new.hyperparams,
        new.randomization,
        new.worker_tracks,
        new.seed,
        new.car,
        notes=notes,
        randomization_update=new.randomization_update,
        race=new.race,
    )
    run = run.model_copy(update={"max_policy_lag": new.max_policy_lag, "segment_steps": new.segment_steps})
    if new.pretrained:
        run = check_pretrained(runs, run, files, new.pretrained)
    return run, files, notes


def trainer_role_run(
    runs: RunStore, run_id: str | None, config: Path | None, files: Path | None, resume: bool, new: NewRun
) -> tuple[RunConfig, dict[str, bytes], bool]:
    """The run ``racer trainer`` trains, its files and whether it resumes: from ``config`` (and the ``files``
    folder) written by ``racer train``; on ``resume`` the stored run; else a new run from ``new``. A run that
    already has checkpoints is always resumed: a restarted trainer (compose's restart: on-failure, a crashed
    host) continues its run, never restarts it."""
    run_files: dict[str, bytes] = {}
    if config:
        run = load_json_model(config, "run config", RunConfig, OptionError)
        if files:
            run_files = {p.name: p.read_bytes() for p in files.iterdir() if p.is_file() and p.name != config.name}
    elif resume:
        if not run_id:
            raise OptionError("--resume needs --run-id")
        run = runs.read_config(run_id)
    elif not run_id:
        raise OptionError("give --run-id (or RACER_RUN_ID) or --config")
    else:
        run, run_files = build_run(run_id, new.track, new.reward_fn, new.action_space, new.hyperparams, race=new.race)
    if not resume and runs.newest_whole(run.run_id) is not None:
        logging.getLogger("racer.trainer").warning(
            "run %s already has checkpoints in %s: continuing it (as --resume)", run.run_id, runs.store.uri
        )
        return runs.read_config(run.run_id), {}, True
    return run, run_files, resume
