"""Turn ``racer train`` / ``racer trainer`` options into a RunConfig and the run's files."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from common.action_space import ActionSpace, default_action_space, load_action_space
from common.car_calibration import CarCalibration, load_car
from common.config import (
    EnvConfig,
    PolicyConfig,
    PretrainedError,
    RandomizationConfig,
    RunConfig,
    WorkerEnv,
    network_from_metadata,
)
from common.errors import OptionError, UserError, first_validation_error
from common.hyperparams import Hyperparameters, HyperparametersError, load_hyperparameters
from common.jsonfile import load_json_model
from common.race import RaceConfig, RaceType
from model_store import RunStore, StoreError
from racer.drfc import DrfcImport, WorkerSettings, read_worker_settings
from racer.options import RunOptions


def build_run(
    run_id: str, opts: RunOptions | None = None, notes: list[str] | None = None, **options: Any
) -> tuple[RunConfig, dict[str, bytes]]:
    """Validate the user's files now (before any process starts) and build the run's config and files from ``opts``
    (``RunOptions``) with ``options`` (its field names: ``track=…``, ``hyperparams=…``) set on top.

    ``notes`` (if given) collects one line per thing in the files that racer accepts but does not use.
    """
    # The simulator is imported here, not with the module: the trainer role reads its run from racer train's
    # --config through this module and builds no env.
    from sim.env import preflight_reward
    from sim.reward import example_path
    from sim.track import load_track

    opts = RunOptions.model_validate({**(opts or RunOptions()).model_dump(), **options}).with_defaults()
    track, action_space, hyperparams = str(opts.track), opts.action_space, opts.hyperparams
    load_track(track)
    reward_path = Path(opts.reward_fn) if opts.reward_fn else example_path("default")
    actions = load_action_space(action_space) if action_space else default_action_space()
    hp = load_hyperparameters(hyperparams) if hyperparams else Hyperparameters()
    if notes is not None and hp.ignored():
        notes.append(f"{hyperparams}: accepted, not used by racer: {', '.join(hp.ignored())}")
    dr = load_randomization(opts.randomization) if opts.randomization else None
    car = load_car(opts.car_calibration) if opts.car_calibration else CarCalibration()
    dr = (dr or RandomizationConfig()).model_copy(update=opts.randomization_update)
    env = EnvConfig(
        track=track,
        randomization=RandomizationConfig.model_validate(dr.model_dump()),
        car=car,
        race=opts.race or RaceConfig(),
    )
    # A broken reward function fails here, naming the user's file, before any process starts. The check drives a
    # throwaway env (its own copy of the reward module) on the run's track, so nothing it caches reaches training.
    user_files = {"reward_fn": str(reward_path), "action_space": action_space}
    preflight_reward(env.model_copy(update=user_files))
    workers = worker_envs(env, opts.worker_settings, notes)
    for worker in {w.model_dump_json(): w for w in workers if w.track or w.race}.values():
        # Each world a worker drives is checked as the run's is: its track loads, its race fits, the reward runs.
        preflight_reward(worker.apply(env).model_copy(update=user_files))
    if hp.greedy_action != "mean" and actions.discrete:
        # Nothing is accepted that racer cannot honour: a discrete policy acts greedily by its argmax.
        raise HyperparametersError(
            f"{hyperparams}: greedy_action {hp.greedy_action!r} applies to a continuous action space; "
            f"{action_space or 'the default action space'} is discrete"
        )
    policy = PolicyConfig(
        network=network_from_metadata(actions.neural_network), stack_size=hp.stack_size, greedy_action=hp.greedy_action
    )
    run = RunConfig(
        run_id=run_id,
        env=env,
        hyperparams=hp,
        policy=policy,
        worker_envs=workers,
        seed=opts.seed,
        max_policy_lag=opts.max_policy_lag,
        segment_steps=opts.segment_steps,
    )
    files = {
        "reward_function.py": reward_path.read_bytes(),
        "model_metadata.json": actions.to_json().encode(),
        "hyperparameters.json": hp.to_json().encode(),
    }
    return run, files


def worker_envs(env: EnvConfig, settings: list[WorkerSettings | None], notes: list[str] | None) -> list[WorkerEnv]:
    """Each worker's world from what its file changes (None: the run's ``env``); a track that does not load or a
    randomization the run's cannot take is a one-line error naming the worker's file."""
    from sim.track import load_track

    out: list[WorkerEnv] = []
    for item in settings:
        if item is None:
            out.append(WorkerEnv())
            continue
        try:
            if item.track:
                load_track(item.track)
            randomization = None
            if item.randomization is not None:
                merged = {**env.randomization.model_dump(), **item.randomization}
                randomization = RandomizationConfig.model_validate(merged)
        except ValidationError as exc:
            reason = f"randomization.{first_validation_error(exc)}"
            raise WorkerConfigError(f"worker config {str(item.source)!r}: {reason}") from None
        except (ValueError, UserError) as exc:
            raise WorkerConfigError(f"worker config {str(item.source)!r}: {str(exc).splitlines()[0]}") from None
        out.append(WorkerEnv(track=item.track, race=item.race, randomization=randomization))
        if notes is not None and item.unmapped:
            notes.append(f"{item.source}: no racer meaning, not used: {', '.join(item.unmapped)}")
    return out if any(w != WorkerEnv() for w in out) else []


class WorkerConfigError(UserError, ValueError):
    """A per-worker configuration racer cannot use; the one-line message names the file or option and the value."""


def parse_worker_configs(values: list[str], workers: int | None) -> list[WorkerSettings | None]:
    """``--worker-config`` values: ``N=FILE`` (worker N, from 1 as in DRfC, drives the world of a DRfC-style
    ``worker-N.env``, each file over the run's settings), or one YAML/JSON file holding a list (entry i is worker
    i+1: null, or a mapping of ``track``, ``race`` (``common/race.py: RaceConfig``) and ``randomization`` fields set
    on the run's). ``workers`` (None: not known here, as in ``racer trainer``) bounds N."""
    if len(values) == 1 and "=" not in values[0]:
        settings = _worker_list(Path(values[0]))
    else:
        numbered: dict[int, WorkerSettings] = {}
        for value in values:
            number, sep, file = value.partition("=")
            if not sep or not number.strip().isdigit() or not file:
                raise OptionError(f"--worker-config {value!r}: expected N=FILE (worker-2.env) or one YAML list file")
            n = int(number)
            if n < 1 or (workers is not None and n > workers):
                raise OptionError(f"--worker-config {value!r}: worker {n} is not one of 1..{workers} (--workers)")
            numbered[n] = read_worker_settings(_existing(Path(file), value))
        settings = [numbered.get(n) for n in range(1, (workers or max(numbered)) + 1)]
    if workers is not None and len(settings) > workers:
        raise OptionError(f"--worker-config: {len(settings)} worker entries for {workers} workers (--workers)")
    return settings


def worker_settings(
    tracks: list[str] | None, configs: list[str] | None, workers: int | None, drfc: DrfcImport | None
) -> list[WorkerSettings | None]:
    """Each worker's world from ``--worker-track``, ``--worker-config`` or a DRfC folder's multi-config, one of them
    (options win over the folder; the two options together are refused, as they would say it twice)."""
    if tracks and configs:
        raise OptionError("--worker-track and --worker-config both set each worker's track: give one of them")
    if configs:
        return parse_worker_configs(configs, workers)
    if tracks:
        return [WorkerSettings(source=Path("--worker-track"), track=t) for t in tracks]
    return list(drfc.worker_settings) if drfc is not None else []


def _existing(path: Path, value: str) -> Path:
    if not path.is_file():
        raise OptionError(f"--worker-config {value!r}: {str(path)!r} is not a file")
    return path


def _worker_list(path: Path) -> list[WorkerSettings | None]:
    import yaml

    try:
        data = yaml.safe_load(_existing(path, str(path)).read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise WorkerConfigError(f"worker config {str(path)!r}: {str(exc).splitlines()[0]}") from None
    if not isinstance(data, list):
        raise WorkerConfigError(f"worker config {str(path)!r}: expected a list (entry i is worker i+1)")
    return [_worker_entry(path, i, entry) for i, entry in enumerate(data)]


_ENTRY_KEYS = ("track", "race", "randomization")


def _worker_entry(path: Path, index: int, entry: object) -> WorkerSettings | None:
    """Entry ``index`` of a worker list file as WorkerSettings; errors name the file, the entry and the key."""
    if entry is None or entry == {}:
        return None
    where = f"worker config {str(path)!r} entry {index + 1}"
    if not isinstance(entry, dict):
        raise WorkerConfigError(f"{where}: expected a mapping of {', '.join(_ENTRY_KEYS)}, got {entry!r}")
    unknown = sorted(set(entry) - set(_ENTRY_KEYS))
    if unknown:
        raise WorkerConfigError(f"{where}: unknown key {unknown[0]!r} (expected {', '.join(_ENTRY_KEYS)})")
    track, race, randomization = entry.get("track"), entry.get("race"), entry.get("randomization")
    if track is not None and not isinstance(track, str):
        raise WorkerConfigError(f"{where}: track {track!r} is not a name or a path")
    if randomization is not None and not isinstance(randomization, dict):
        raise WorkerConfigError(f"{where}: randomization {randomization!r} is not a mapping")
    try:
        race_cfg = RaceConfig.model_validate(race) if race is not None else None
    except ValidationError as exc:
        raise WorkerConfigError(f"{where}: race: {first_validation_error(exc)}") from None
    return WorkerSettings(source=path, track=track, race=race_cfg, randomization=randomization)


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


def open_run(runs: RunStore, opts: RunOptions) -> tuple[RunConfig, dict[str, bytes], list[str]]:
    """The run ``racer train`` trains (``opts.run_id``): on ``opts.resume`` the stored one; else a new run built
    from the user's files, checked now, and refused if the run already has checkpoints. Either way the options are
    checked against it (``RunOptions.check_run``). Returns its config, its files (none on a resume) and one note per
    thing in the files that racer accepts but does not use."""
    run_id = str(opts.run_id)
    if opts.resume:
        run = runs.read_config(run_id)
        opts.check_run(run)
        return run, {}, []
    if runs.newest_whole(run_id) is not None:
        raise OptionError(
            f"run {run_id!r} already exists in {runs.store.uri}: add --resume to continue it, "
            "or choose another --run-id"
        )
    notes: list[str] = []
    run, files = build_run(run_id, opts, notes)
    if opts.pretrained:
        run = check_pretrained(runs, run, files, opts.pretrained)
    opts.check_run(run)
    return run, files, notes


def trainer_role_run(
    runs: RunStore, config: Path | None, files: Path | None, opts: RunOptions
) -> tuple[RunConfig, dict[str, bytes], bool]:
    """The run ``racer trainer`` trains, its files and whether it resumes: from ``config`` (and the ``files``
    folder) written by ``racer train``, which checked it; on ``opts.resume`` the stored run; else a new run from
    ``opts``. A run that already has checkpoints is always resumed: a restarted trainer (compose's restart:
    on-failure, a crashed host) continues its run, never restarts it."""
    run_files: dict[str, bytes] = {}
    resume = opts.resume
    if config:
        run = load_json_model(config, "run config", RunConfig, OptionError)
        if files:
            run_files = {p.name: p.read_bytes() for p in files.iterdir() if p.is_file() and p.name != config.name}
    else:
        if not opts.run_id:
            raise OptionError("--resume needs --run-id" if resume else "give --run-id (or RACER_RUN_ID) or --config")
        if resume:
            run = runs.read_config(opts.run_id)
        else:
            run, run_files = build_run(opts.run_id, opts)
        opts.check_run(run)
    if not resume and runs.newest_whole(run.run_id) is not None:
        logging.getLogger("racer.trainer").warning(
            "run %s already has checkpoints in %s: continuing it (as --resume)", run.run_id, runs.store.uri
        )
        return runs.read_config(run.run_id), {}, True
    return run, run_files, resume
