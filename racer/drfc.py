"""Coming from DeepRacer-for-Cloud (DRfC): read a DRfC ``custom_files/`` folder and its ``run.env``.

A DRfC user keeps ``reward_function.py``, ``model_metadata.json`` and ``hyperparameters.json`` in
``custom_files/`` and the run's settings as ``DR_*`` variables in ``run.env`` (and ``system.env``).
:func:`import_drfc` finds those files and maps every variable that has a racer meaning; the others are
returned in :attr:`DrfcImport.unmapped`, listed by ``racer train`` and ``racer check`` under their table of the
variables racer reads (``racer/check.py: drfc_lines``), so that nothing is dropped silently. Variables whose
value racer cannot honour (another race type, a track racer does not ship) are a one-line :class:`DrfcError`
naming the file, the variable and the value.

The variables' meanings follow DRfC's ``defaults/template-run.env`` and the simapp's use of them
(``markov/agent_ctrl/rollout_agent_ctrl.py``: ``change_start`` advances the start by
``round_robin_advance_dist`` of a lap each episode; ``alternate_driving_direction`` flips the direction
each episode).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from common.errors import UserError, first_validation_error
from common.race import RaceConfig, RaceType, race_config_from_drfc

CUSTOM_FILES = ("reward_function.py", "model_metadata.json", "hyperparameters.json")
_LINE = re.compile(r"^\s*(?:export\s+)?([A-Za-z_][A-Za-z0-9_]*)\s*=\s*(.*?)\s*$")


class DrfcError(UserError, ValueError):
    """A DRfC folder or variable racer cannot use; the one-line message names the file, the variable, the value."""


@dataclass
class DrfcImport:
    """What a DRfC folder asks for, in racer's terms (None = not set there)."""

    folder: Path
    reward_fn: Path | None = None
    action_space: Path | None = None
    hyperparams: Path | None = None
    env_files: list[Path] = field(default_factory=list)
    track: str | None = None
    workers: int | None = None
    run_id: str | None = None
    eval_episodes: int | None = None
    randomization: dict[str, Any] = field(default_factory=dict)
    """RandomizationConfig fields to set."""
    pretrained: str | None = None
    """``RUN:CHECKPOINT`` to start from (DR_LOCAL_S3_PRETRAINED)."""
    mapped: dict[str, str] = field(default_factory=dict)
    """Each variable used, with what racer does with it (the racer setting and the value it gets)."""
    ignored: dict[str, str] = field(default_factory=dict)
    """Each variable racer knows that changes nothing as set here, with why (its value, or another variable's)."""
    values: dict[str, str] = field(default_factory=dict)
    """The value of each variable in ``mapped`` and ``ignored``, as the files set it."""
    unmapped: list[str] = field(default_factory=list)
    """DR_* variables set in the files that have no racer meaning (yet)."""
    track_error: DrfcError | None = None
    """DR_WORLD_NAME names a track racer does not ship: the error to raise unless --track is given."""
    race: RaceConfig | None = None
    """The race of DR_RACE_TYPE, DR_OA_*, DR_H2B_* and the evaluation penalties (None: none of them set)."""
    multi_config: bool = False
    """DR_TRAIN_MULTI_CONFIG: workers 2..N read their own ``worker-N.env``."""
    worker_settings: list[WorkerSettings | None] = field(default_factory=list)
    """Per worker (index 0 = DRfC's worker 1, which drives run.env) what its worker-N.env changes."""


_VAR = re.compile(r"\$(?:\{([A-Za-z_][A-Za-z0-9_]*)\}|([A-Za-z_][A-Za-z0-9_]*))")


def _expand(value: str, known: dict[str, str]) -> str:
    """``$VAR`` and ``${VAR}`` replaced as the shell that sources a DRfC .env file replaces them (unset: empty)."""
    return _VAR.sub(lambda m: known.get(m.group(1) or m.group(2), os.environ.get(m.group(1) or m.group(2), "")), value)


def read_env_file(path: Path, known: dict[str, str] | None = None) -> dict[str, str]:
    """``KEY=value`` lines of a DRfC .env file, read as DRfC's scripts read it (they ``source`` it): comments, blank
    lines and quotes as a shell reads them, and ``$VAR`` expanded from earlier lines, ``known`` and the environment
    (not inside single quotes)."""
    values: dict[str, str] = {}
    known = dict(known or {})
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DrfcError(f"DRfC file {str(path)!r} cannot be read: {exc}") from None
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        m = _LINE.match(line)
        if not m:
            raise DrfcError(f"DRfC file {str(path)!r} line {number}: expected KEY=value, got {line[:80]!r}")
        key, value = m.group(1), m.group(2)
        if value[:1] == "'" and value[-1:] == "'" and len(value) >= 2:
            value = value[1:-1]
        elif value[:1] == '"' and value[-1:] == '"' and len(value) >= 2:
            value = _expand(value[1:-1], known)
        else:
            value = _expand(value.split(" #", 1)[0].strip(), known)
        values[key] = known[key] = value
    return values


def _find(folder: Path, name: str) -> Path | None:
    for candidate in (folder / name, folder / "custom_files" / name, folder.parent / name):
        if candidate.is_file():
            return candidate
    return None


def import_drfc(folder: str | Path) -> DrfcImport:
    """Read a DRfC folder (its ``custom_files/`` and ``run.env``, optionally ``system.env``); see the module doc."""
    root = Path(folder)
    if not root.is_dir():
        raise DrfcError(f"DRfC folder {str(root)!r} does not exist")
    out = DrfcImport(folder=root)
    out.reward_fn = _find(root, "reward_function.py")
    out.action_space = _find(root, "model_metadata.json")
    out.hyperparams = _find(root, "hyperparameters.json")
    env: dict[str, tuple[str, Path]] = {}
    for name in ("system.env", "run.env"):  # run.env last: its values win, as in DRfC's scripts
        path = _find(root, name)
        if path is not None:
            out.env_files.append(path)
            known = {k: v for k, (v, _) in env.items()}
            env.update({k: (v, path) for k, v in read_env_file(path, known).items()})
    if not (out.reward_fn or out.action_space or out.hyperparams or out.env_files):
        raise DrfcError(
            f"DRfC folder {str(root)!r} holds none of {', '.join(CUSTOM_FILES)}, run.env (also looked in custom_files/)"
        )
    _apply(out, env)
    if out.multi_config and (out.workers or 1) > 1:
        out.worker_settings = _multi_config(root, env, out.workers or 1)
    return out


def _apply(out: DrfcImport, env: dict[str, tuple[str, Path]]) -> None:
    """Map each variable of ``env`` (value, file) into ``out``."""
    for key, (value, path) in env.items():
        handler = _HANDLERS.get(key)
        if handler is None:
            if key.startswith("DR_"):
                out.unmapped.append(key)
            continue
        out.values[key] = value
        meaning = handler(out, value, _Where(path, key, value))
        if meaning:
            out.mapped[key] = meaning
    _finish_start_positions(out, env)
    _finish_race(out, env)
    for key in out.values:
        if key in out.mapped:
            out.ignored.pop(key, None)
        else:
            out.ignored.setdefault(key, "no effect with this value")
    if out.randomization.get("reverse_prob") and out.randomization.get("alternate_direction"):
        value, path = env["DR_TRAIN_REVERSE_DIRECTION"]
        where = _Where(path, "DR_TRAIN_REVERSE_DIRECTION", value)
        raise where.error("racer's alternation starts forward; unset DR_TRAIN_ALTERNATE_DRIVING_DIRECTION or this")


@dataclass(frozen=True)
class _Where:
    path: Path
    key: str
    value: str

    def error(self, why: str) -> DrfcError:
        return DrfcError(f"DRfC file {str(self.path)!r}: {self.key}={self.value!r}: {why}")


def _bool(where: _Where) -> bool:
    v = where.value.strip().lower()
    if v in ("true", "1", "yes"):
        return True
    if v in ("false", "0", "no", ""):
        return False
    raise where.error("expected True or False")


def _number(where: _Where, kind: type, low: float, high: float) -> Any:
    try:
        value = kind(where.value)
    except ValueError:
        raise where.error(f"expected a{'n integer' if kind is int else ' number'}") from None
    if not low <= value <= high:
        raise where.error(f"expected a value in [{low:g}, {high:g}]")
    return value


def _world(out: DrfcImport, value: str, where: _Where) -> str:
    from sim.track import TrackError, track_source

    try:
        track_source(value)
    except TrackError as exc:
        # Raised only if no --track is given: the user may pass the track's .npy instead.
        out.track_error = where.error(f"{exc}; or give --track with its .npy file")
        out.ignored[where.key] = "not a track racer has: --track decides"
        return ""
    out.track = value
    return f"--track {value}"


def _race_type(out: DrfcImport, value: str, where: _Where) -> str:
    names = [t.value for t in RaceType]
    if value.strip() not in names:
        raise where.error(f"expected one of {', '.join(names)}")
    return f"race type {value.strip()}"


_RACE_NUMBERS: dict[str, tuple[type, float, float]] = {
    "DR_OA_NUMBER_OF_OBSTACLES": (int, 0, 20),
    "DR_OA_MIN_DISTANCE_BETWEEN_OBSTACLES": (float, 0.0, 100.0),
    "DR_H2B_NUMBER_OF_BOT_CARS": (int, 0, 10),
    "DR_H2B_BOT_CAR_SPEED": (float, 0.01, 10.0),
    "DR_H2B_MIN_DISTANCE_BETWEEN_BOT_CARS": (float, 0.0, 100.0),
    "DR_H2B_LOWER_LANE_CHANGE_TIME": (float, 0.0, 3600.0),
    "DR_H2B_UPPER_LANE_CHANGE_TIME": (float, 0.0, 3600.0),
    "DR_H2B_LANE_CHANGE_DISTANCE": (float, 0.01, 100.0),
    "DR_H2B_BOT_CAR_PENALTY": (float, 0.0, 3600.0),
    "DR_EVAL_OFF_TRACK_PENALTY": (float, 0.0, 3600.0),
    "DR_COLLISION_PENALTY": (float, 0.0, 3600.0),
    "DR_EVAL_MAX_RESETS": (int, 0, 10000),
    "DR_EVAL_RESET_BEHIND_DIST": (float, 0.0, 100.0),
}
"""The race's numeric DRfC variables with their type and sensible range (common/race.py maps them)."""
_RACE_BOOLS = (
    "DR_OA_RANDOMIZE_OBSTACLE_LOCATIONS",
    "DR_OA_IS_OBSTACLE_BOT_CAR",
    "DR_H2B_RANDOMIZE_BOT_CAR_LOCATIONS",
    "DR_H2B_IS_LANE_CHANGE",
)
_RACE_TEXT = ("DR_OA_OBSTACLE_TYPE", "DR_OA_OBJECT_POSITIONS")


def _race_variable(out: DrfcImport, value: str, where: _Where) -> str:
    """Check one race variable's form here (to name its file); :func:`_finish_race` builds the race."""
    if where.key in _RACE_NUMBERS:
        _number(where, *_RACE_NUMBERS[where.key])
    elif where.key in _RACE_BOOLS and value.strip().lower() not in ("true", "false"):
        # The simapp's str2bool knows only true/false: any other text stays a (truthy) string there.
        raise where.error("expected True or False")
    return ""  # the race's field and value, once the race is built (_finish_race)


def _evaluation_collision(out: DrfcImport, value: str, where: _Where) -> str:
    # DRfC's template sets it, but its scripts/evaluation/prepare-config.py reads DR_COLLISION_PENALTY instead.
    out.ignored[where.key] = "not read by DRfC either (its evaluation reads DR_COLLISION_PENALTY)"
    return ""


def _workers(out: DrfcImport, value: str, where: _Where) -> str:
    out.workers = _number(where, int, 1, 64)
    return f"--workers {out.workers}"


def run_id_from_prefix(prefix: str) -> str | None:
    """The racer run id for a DRfC S3 model prefix (``training/model-1`` is ``training-model-1``): a run id takes
    letters, digits, '.', '_' and '-' only. The same mapping serves the model and the pretrained prefix, so a run
    imported from DRfC is found again under the name DRfC's pretrained prefix gives it."""
    rid = re.sub(r"[^A-Za-z0-9._-]+", "-", prefix.strip()).strip("-.")
    return rid or None


def _model_prefix(out: DrfcImport, value: str, where: _Where) -> str:
    rid = run_id_from_prefix(value)
    if rid is None:
        raise where.error("a run id needs at least one letter or digit")
    out.run_id = rid
    return f"--run-id {rid}"


def _eval_trials(out: DrfcImport, value: str, where: _Where) -> str:
    out.eval_episodes = _number(where, int, 1, 100)
    return f"--eval-episodes {out.eval_episodes} (starts per direction of racer's evaluator)"


def _alternate(out: DrfcImport, value: str, where: _Where) -> str:
    out.randomization["alternate_direction"] = _bool(where)
    return f"alternate_direction {out.randomization['alternate_direction']}"


def _reverse(out: DrfcImport, value: str, where: _Where) -> str:
    # The simapp's REVERSE_DIR is the first episode's direction, which alternate_driving_direction then flips
    # (track_data.py, rollout_agent_ctrl.py); racer's alternation always starts forward, so the pair is refused.
    if not _bool(where):
        out.ignored[where.key] = "False: episodes start in the track's direction"
        return ""
    out.randomization["reverse_prob"] = 1.0
    return "reverse_prob 1 (every episode driven in reverse)"


def _multi(out: DrfcImport, value: str, where: _Where) -> str:
    out.multi_config = _bool(where)
    return "per-worker configurations from worker-N.env" if out.multi_config else ""


def _noted(out: DrfcImport, value: str, where: _Where) -> str:
    _bool(where) if where.key == "DR_TRAIN_CHANGE_START_POSITION" else _number(where, float, 0.0, 1.0)
    return ""  # the start positions the pair sets, once both are read (_finish_start_positions)


def _pretrained(out: DrfcImport, value: str, where: _Where) -> str:
    if not _bool(where):
        out.ignored[where.key] = "False: the run starts from fresh weights"
    return ""  # the --pretrained it sets, once its prefix and checkpoint are read (_finish_start_positions)


def _unused_when_empty(out: DrfcImport, value: str, where: _Where) -> str:
    return ""  # read with DR_LOCAL_S3_PRETRAINED (_finish_start_positions)


_HANDLERS = {
    "DR_WORLD_NAME": _world,
    "DR_RACE_TYPE": _race_type,
    **{key: _race_variable for key in (*_RACE_NUMBERS, *_RACE_BOOLS, *_RACE_TEXT)},
    "DR_EVAL_COLLISION_PENALTY": _evaluation_collision,
    "DR_WORKERS": _workers,
    "DR_LOCAL_S3_MODEL_PREFIX": _model_prefix,
    "DR_EVAL_NUMBER_OF_TRIALS": _eval_trials,
    "DR_TRAIN_ALTERNATE_DRIVING_DIRECTION": _alternate,
    "DR_TRAIN_REVERSE_DIRECTION": _reverse,
    "DR_TRAIN_MULTI_CONFIG": _multi,
    "DR_TRAIN_CHANGE_START_POSITION": _noted,
    "DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST": _noted,
    "DR_LOCAL_S3_PRETRAINED": _pretrained,
    "DR_LOCAL_S3_PRETRAINED_PREFIX": _unused_when_empty,
    "DR_LOCAL_S3_PRETRAINED_CHECKPOINT": _unused_when_empty,
}


def _finish_start_positions(out: DrfcImport, env: dict[str, tuple[str, Path]]) -> None:
    """Start positions and the pretrained model, which each take two or three variables together."""
    change = env.get("DR_TRAIN_CHANGE_START_POSITION")
    if change is not None:
        advance = env.get("DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST", ("0.05", change[1]))
        step = _number(_Where(advance[1], "DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST", advance[0]), float, 0.0, 1.0)
        if _bool(_Where(change[1], "DR_TRAIN_CHANGE_START_POSITION", change[0])) and step > 0:
            # The simapp advances the start by `step` of a lap each episode; racer's round robin splits the lap
            # into equal parts by waypoint.
            out.randomization.update(random_start=False, round_robin_divisions=max(1, round(1 / step)))
        else:
            out.randomization.update(random_start=False, round_robin_divisions=1)  # always the first waypoint
        divisions = out.randomization["round_robin_divisions"]
        out.mapped["DR_TRAIN_CHANGE_START_POSITION"] = f"random_start False, round_robin_divisions {divisions}"
        if "DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST" in env:
            out.mapped["DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST"] = (
                f"round_robin_divisions {divisions} (the lap in parts of {step:g})"
                if divisions > 1
                else "round_robin_divisions 1 (always the first waypoint)"
            )
    elif "DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST" in env:
        out.ignored["DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST"] = "not used without DR_TRAIN_CHANGE_START_POSITION"
    pre = env.get("DR_LOCAL_S3_PRETRAINED")
    if pre is not None and _bool(_Where(pre[1], "DR_LOCAL_S3_PRETRAINED", pre[0])):
        prefix = env.get("DR_LOCAL_S3_PRETRAINED_PREFIX")
        if prefix is None or not prefix[0]:
            raise _Where(pre[1], "DR_LOCAL_S3_PRETRAINED", pre[0]).error("needs DR_LOCAL_S3_PRETRAINED_PREFIX")
        checkpoint = env.get("DR_LOCAL_S3_PRETRAINED_CHECKPOINT", ("last", pre[1]))[0].strip().lower() or "last"
        if checkpoint not in ("last", "best") and not checkpoint.isdigit():
            where = _Where(pre[1], "DR_LOCAL_S3_PRETRAINED_CHECKPOINT", checkpoint)
            raise where.error("expected last, best or a checkpoint number")
        source = run_id_from_prefix(prefix[0])
        if source is None:
            raise _Where(prefix[1], "DR_LOCAL_S3_PRETRAINED_PREFIX", prefix[0]).error("names no run")
        out.pretrained = f"{source}:{'latest' if checkpoint == 'last' else checkpoint}"
        out.mapped["DR_LOCAL_S3_PRETRAINED"] = f"--pretrained {out.pretrained}"
        for key in ("DR_LOCAL_S3_PRETRAINED_PREFIX", "DR_LOCAL_S3_PRETRAINED_CHECKPOINT"):
            if key in env:
                out.mapped[key] = f"--pretrained {out.pretrained}"
    else:
        for key in ("DR_LOCAL_S3_PRETRAINED_PREFIX", "DR_LOCAL_S3_PRETRAINED_CHECKPOINT"):
            if key in env:
                out.ignored[key] = "not used: DR_LOCAL_S3_PRETRAINED is not True"


def _finish_race(out: DrfcImport, env: dict[str, tuple[str, Path]]) -> None:
    """The race DRfC's variables describe (``common/race.py: race_config_from_drfc`` reads them as DRfC's scripts
    do, with the evaluation penalties racer's evaluator applies); a value the race refuses names its file."""
    keys = ("DR_RACE_TYPE", *_RACE_NUMBERS, *_RACE_BOOLS, *_RACE_TEXT)
    given = {key: env[key] for key in keys if key in env}
    if not given:
        return
    values = {key: value.strip() for key, (value, _) in given.items()}
    try:
        out.race = race_config_from_drfc(values, evaluation=True)
    except ValidationError as exc:
        files = ", ".join(sorted({str(path) for _, path in given.values()}))
        raise DrfcError(f"DRfC file {files!r}: race settings: {first_validation_error(exc)}") from None
    except ValueError as exc:
        files = ", ".join(sorted({str(path) for _, path in given.values()}))
        raise DrfcError(f"DRfC file {files!r}: {exc}") from None
    race = out.race
    summary = f"{race.race_type.value}"
    if race.obstacle_count:
        summary += f", {race.obstacle_count} obstacles"
    if race.bot_car_count:
        summary += f", {race.bot_car_count} bot cars at {race.head_to_bot.bot_car_speed:g} m/s"
    out.mapped["DR_RACE_TYPE"] = f"race {summary}"
    for key in given:
        if key != "DR_RACE_TYPE":
            _race_field(out, key, race)


RACE_FIELDS: dict[str, tuple[str, str]] = {
    "DR_OA_NUMBER_OF_OBSTACLES": ("object_avoidance", "number_of_obstacles"),
    "DR_OA_MIN_DISTANCE_BETWEEN_OBSTACLES": ("object_avoidance", "min_distance_between_obstacles"),
    "DR_OA_RANDOMIZE_OBSTACLE_LOCATIONS": ("object_avoidance", "randomize_obstacle_locations"),
    "DR_OA_IS_OBSTACLE_BOT_CAR": ("object_avoidance", "is_obstacle_bot_car"),
    "DR_OA_OBSTACLE_TYPE": ("object_avoidance", "obstacle_type"),
    "DR_OA_OBJECT_POSITIONS": ("object_avoidance", "object_positions"),
    "DR_H2B_IS_LANE_CHANGE": ("head_to_bot", "is_lane_change"),
    "DR_H2B_LOWER_LANE_CHANGE_TIME": ("head_to_bot", "lower_lane_change_time"),
    "DR_H2B_UPPER_LANE_CHANGE_TIME": ("head_to_bot", "upper_lane_change_time"),
    "DR_H2B_LANE_CHANGE_DISTANCE": ("head_to_bot", "lane_change_distance"),
    "DR_H2B_NUMBER_OF_BOT_CARS": ("head_to_bot", "number_of_bot_cars"),
    "DR_H2B_MIN_DISTANCE_BETWEEN_BOT_CARS": ("head_to_bot", "min_distance_between_bot_cars"),
    "DR_H2B_RANDOMIZE_BOT_CAR_LOCATIONS": ("head_to_bot", "randomize_bot_car_locations"),
    "DR_H2B_BOT_CAR_SPEED": ("head_to_bot", "bot_car_speed"),
    "DR_H2B_BOT_CAR_PENALTY": ("head_to_bot", "penalty_seconds"),
    "DR_EVAL_OFF_TRACK_PENALTY": ("penalties", "off_track_penalty"),
    "DR_COLLISION_PENALTY": ("penalties", "collision_penalty"),
    "DR_EVAL_MAX_RESETS": ("penalties", "number_of_resets"),
    "DR_EVAL_RESET_BEHIND_DIST": ("penalties", "reset_behind_dist"),
}
"""The ``RaceConfig`` field (section, name) each race variable sets, as ``common.race.race_config_from_drfc`` reads
them (a test holds the two together), for saying what racer made of each."""
_SECTION_RACE = {"object_avoidance": RaceType.OBJECT_AVOIDANCE, "head_to_bot": RaceType.HEAD_TO_BOT}


def _race_field(out: DrfcImport, key: str, race: RaceConfig) -> None:
    """What one race variable became: its field and value, or why it changes nothing in this race."""
    section, name = RACE_FIELDS[key]
    needs = _SECTION_RACE.get(section)
    if needs is not None and race.race_type is not needs:
        out.ignored[key] = f"not used: the race is {race.race_type.value}"
        return
    value = getattr(getattr(race, section), name)
    if isinstance(value, list):
        shown = f"{len(value)} positions"
    elif isinstance(value, float):
        shown = f"{value:g}"
    else:
        shown = str(value)
    where = " (racer eval's resets)" if section == "penalties" else ""
    out.mapped[key] = f"{section}.{name} {shown}{where}"


@dataclass
class WorkerSettings:
    """What one worker's DRfC env file changes (None = the run's): the parts of ``common.config.WorkerEnv`` that
    can be read without the run's own randomization, which ``randomization`` updates."""

    source: Path
    track: str | None = None
    race: RaceConfig | None = None
    randomization: dict[str, Any] | None = None
    """RandomizationConfig fields to set on the run's randomization for this worker."""
    unmapped: list[str] = field(default_factory=list)


_RANDOMIZATION_KEYS = (
    "DR_TRAIN_ALTERNATE_DRIVING_DIRECTION",
    "DR_TRAIN_CHANGE_START_POSITION",
    "DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST",
    "DR_TRAIN_REVERSE_DIRECTION",
)
_RACE_KEYS = ("DR_RACE_TYPE", *_RACE_NUMBERS, *_RACE_BOOLS, *_RACE_TEXT)
PER_WORKER_KEYS = frozenset(
    (
        "DR_WORLD_NAME",
        *_RACE_KEYS,
        *_RANDOMIZATION_KEYS,
        "DR_ENABLE_DOMAIN_RANDOMIZATION",
        "DR_TRAIN_START_POSITION_OFFSET",
        "DR_CAR_COLOR",
        "DR_CAR_BODY_SHELL_TYPE",
        "DR_CAMERA_MAIN_ENABLE",
        "DR_CAMERA_SUB_ENABLE",
        "DR_ENABLE_EXTRA_KVS_OVERLAY",
    )
)
"""The variables DRfC's ``scripts/training/prepare-config.py`` writes per worker with DR_TRAIN_MULTI_CONFIG; a
worker file's other variables are not used by DRfC, nor by racer."""


def read_worker_settings(path: Path, base: dict[str, tuple[str, Path]] | None = None) -> WorkerSettings:
    """One worker's env file (DRfC's ``worker-N.env`` form) read over the variables ``base`` (value, file) already
    set. A field is set only where the file sets one of its variables, so a run's ``--track`` or ``--race`` holds
    for the worker unless its file says otherwise."""
    base = dict(base or {})
    known = {k: v for k, (v, _) in base.items()}
    own = {k: (v, path) for k, v in read_env_file(path, known).items()}
    merged = {k: item for k, item in {**base, **own}.items() if k in PER_WORKER_KEYS}
    worker = DrfcImport(folder=path.parent)
    _apply(worker, merged)
    if worker.track_error is not None and "DR_WORLD_NAME" in own:
        raise worker.track_error
    settings = WorkerSettings(source=path, unmapped=sorted(k for k in worker.unmapped if k in own))
    settings.unmapped += sorted(k for k in own if k not in PER_WORKER_KEYS and k.startswith("DR_"))
    if "DR_WORLD_NAME" in own:
        settings.track = worker.track
    if any(k in own for k in _RACE_KEYS):
        settings.race = worker.race
    if any(k in own for k in _RANDOMIZATION_KEYS):
        settings.randomization = dict(worker.randomization)
    return settings


def _multi_config(root: Path, env: dict[str, tuple[str, Path]], workers: int) -> list[WorkerSettings | None]:
    """Workers 2..N's ``worker-N.env`` beside ``run.env``, read as DRfC's prepare-config.py reads them: each file
    updates the variables the previous workers' files left (they accumulate), worker 1 drives ``run.env``."""
    settings: list[WorkerSettings | None] = [None]
    merged = dict(env)
    for number in range(2, workers + 1):
        path = _find(root, f"worker-{number}.env")
        if path is None:
            raise DrfcError(
                f"DRfC folder {str(root)!r}: DR_TRAIN_MULTI_CONFIG is True with {workers} workers but "
                f"worker-{number}.env is missing"
            )
        settings.append(read_worker_settings(path, merged))
        known = {k: v for k, (v, _) in merged.items()}
        merged.update({k: (v, path) for k, v in read_env_file(path, known).items()})
    return settings
