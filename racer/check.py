"""``racer check``: validate a user's DeepRacer files exactly as ``racer train`` would, and say what racer does with
each, one line per file; and the merging of ``--from-drfc`` with explicit options that ``racer train`` shares."""

from __future__ import annotations

import textwrap
from dataclasses import dataclass, field
from pathlib import Path

from common.defaults import DEFAULT_TRACK
from common.race import RaceConfig
from racer.drfc import DrfcImport, import_drfc


@dataclass
class UserFiles:
    """The user's inputs to a run after ``--from-drfc`` is merged in (explicit options win)."""

    track: str = DEFAULT_TRACK
    reward_fn: str | None = None
    action_space: str | None = None
    hyperparams: str | None = None
    workers: int | None = None
    run_id: str | None = None
    eval_episodes: int | None = None
    pretrained: str | None = None
    randomization: dict = field(default_factory=dict)
    race: RaceConfig | None = None
    """The race (``--race``/``--race-type``, else a DRfC run.env's); None: a time trial."""
    drfc: DrfcImport | None = None


def merge_inputs(
    track: str | None,
    reward_fn: Path | None,
    action_space: Path | None,
    hyperparams: Path | None,
    from_drfc: Path | None,
    race: RaceConfig | None = None,
) -> UserFiles:
    """The run's inputs: explicit options first, then what a DRfC folder says, then racer's defaults."""
    drfc = import_drfc(from_drfc) if from_drfc else None
    if drfc is not None and drfc.track_error is not None and track is None:
        raise drfc.track_error

    def pick(explicit: object, imported: object) -> str | None:
        chosen = explicit if explicit is not None else imported
        return None if chosen is None else str(chosen)

    return UserFiles(
        track=pick(track, drfc and drfc.track) or DEFAULT_TRACK,
        reward_fn=pick(reward_fn, drfc and drfc.reward_fn),
        action_space=pick(action_space, drfc and drfc.action_space),
        hyperparams=pick(hyperparams, drfc and drfc.hyperparams),
        workers=drfc.workers if drfc else None,
        run_id=drfc.run_id if drfc else None,
        eval_episodes=drfc.eval_episodes if drfc else None,
        pretrained=drfc.pretrained if drfc else None,
        randomization=dict(drfc.randomization) if drfc else {},
        race=race if race is not None else (drfc.race if drfc else None),
        drfc=drfc,
    )


LINE_WIDTH = 110
"""Where ``drfc_lines`` wraps the list of unused variables."""
VALUE_WIDTH = 24
"""A DRfC value longer than this is cut in ``drfc_lines``' table (the file has it whole)."""


def drfc_lines(drfc: DrfcImport | None) -> list[str]:
    """What racer does with a DRfC folder's variables: a table of those racer reads (variable, value, the racer
    setting and value it becomes, or why it changes nothing), then the names of the rest, wrapped."""
    if drfc is None or not drfc.env_files:
        return []
    files = ", ".join(str(p) for p in drfc.env_files)
    rows = [("variable", "value", "racer")]
    for key, meaning in sorted({**drfc.ignored, **drfc.mapped}.items()):
        value = drfc.values.get(key, "")
        rows.append((key, value if len(value) <= VALUE_WIDTH else value[: VALUE_WIDTH - 1] + "…", meaning))
    lines = [f"{files}: the DRfC variables racer reads"]
    if len(rows) > 1:
        key_width, value_width = (max(len(row[i]) for row in rows) for i in (0, 1))
        lines += [f"  {k:<{key_width}}  {v:<{value_width}}  {m}".rstrip() for k, v, m in rows]
    else:
        lines[0] += ": none"
    if drfc.unmapped:  # under the files' line above; wrapped, not one line of 1.5 kB
        names = ", ".join(sorted(drfc.unmapped))
        head = "  no racer meaning, not used: "
        lines += textwrap.wrap(
            names,
            LINE_WIDTH,
            initial_indent=head,
            subsequent_indent="    ",
            break_on_hyphens=False,
            break_long_words=False,
        )
    return lines


def check_files(inputs: UserFiles) -> list[str]:
    """Validate as ``racer train`` does (raising its one-line errors) and describe each file in one line."""
    from common.action_space import ActionSpace
    from racer.runconfig import build_run

    notes: list[str] = []
    run, files = build_run(
        "racer-check",
        inputs.track,
        inputs.reward_fn,
        inputs.action_space,
        inputs.hyperparams,
        worker_settings=list(inputs.drfc.worker_settings) if inputs.drfc else None,
        notes=notes,
        randomization_update=inputs.randomization,
        race=inputs.race,
    )
    # What build_run read and checked, not the files read a second time.
    actions = ActionSpace.model_validate_json(files["model_metadata.json"])
    hp = run.hyperparams
    kind = f"{actions.n} discrete actions" if actions.discrete else "a continuous action space"
    lines = [
        f"{inputs.reward_fn or 'reward function (racer default)'}: ran on {run.env.track} in a throwaway env: ok",
        f"{inputs.action_space or 'model_metadata.json (racer default)'}: {kind}, sensor {', '.join(actions.sensor)}, "
        f"{actions.training_algorithm}, {actions.neural_network} (racer's {run.policy.network} CNN)",
        f"{inputs.hyperparams or 'hyperparameters.json (DeepRacer defaults)'}: batch {hp.batch_size}, lr {hp.lr:g}, "
        f"{hp.num_epochs} epochs every {hp.num_episodes_between_training} episodes, {hp.loss_type} value loss, "
        f"stops after {hp.term_cond_max_episodes} policy updates",
    ]
    lines.append(f"race: {race_line(run.env.race)}")
    for k, worker in enumerate(run.worker_envs):
        lines.append(f"worker {k + 1}: {worker.describe()}")
    lines += notes
    lines += drfc_lines(inputs.drfc)
    return lines


def race_line(race: RaceConfig) -> str:
    """The race in a few words, as ``racer check`` and ``racer train`` print it."""
    text = race.race_type.value
    if race.obstacle_count:
        oa = race.object_avoidance
        where = "fixed" if oa.object_positions else "random" if oa.randomize_obstacle_locations else "evenly spaced"
        text += f", {race.obstacle_count} obstacles ({where})"
    if race.bot_car_count:
        h2b = race.head_to_bot
        text += f", {race.bot_car_count} bot cars at {h2b.bot_car_speed:g} m/s"
        text += ", changing lanes" if h2b.is_lane_change else ""
    return text
