"""``racer check``: validate a user's DeepRacer files exactly as ``racer train`` would, and say what racer does with
each, one line per file; and the merging of ``--from-drfc`` with explicit options that ``racer train`` shares."""

from __future__ import annotations

import textwrap
from pathlib import Path

from common.race import RaceConfig
from racer.drfc import DrfcImport, import_drfc
from racer.options import RunOptions


def merge_inputs(opts: RunOptions, from_drfc: Path | None) -> tuple[RunOptions, DrfcImport | None]:
    """The run's options with a DRfC folder's (read once) filling those left unset, and the folder's import."""
    drfc = import_drfc(from_drfc) if from_drfc else None
    return opts.with_drfc(drfc), drfc


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


def check_files(opts: RunOptions, drfc: DrfcImport | None = None) -> list[str]:
    """Validate as ``racer train`` does (raising its one-line errors) and describe each file in one line; ``drfc``
    is the folder ``opts`` were merged with (its multi-config worker files are checked too)."""
    from common.action_space import ActionSpace
    from racer.runconfig import build_run

    if drfc is not None and not opts.worker_settings:
        opts = opts.model_copy(update={"worker_settings": list(drfc.worker_settings)})
    notes: list[str] = []
    run, files = build_run("racer-check", opts, notes)
    # What build_run read and checked, not the files read a second time.
    actions = ActionSpace.model_validate_json(files["model_metadata.json"])
    hp = run.hyperparams
    kind = f"{actions.n} discrete actions" if actions.discrete else "a continuous action space"
    lines = [
        f"{opts.reward_fn or 'reward function (racer default)'}: ran on {run.env.track} in a throwaway env: ok",
        f"{opts.action_space or 'model_metadata.json (racer default)'}: {kind}, sensor {', '.join(actions.sensor)}, "
        f"{actions.training_algorithm}, {actions.neural_network} (racer's {run.policy.network} CNN)",
        f"{opts.hyperparams or 'hyperparameters.json (DeepRacer defaults)'}: batch {hp.batch_size}, lr {hp.lr:g}, "
        f"{hp.num_epochs} epochs every {hp.num_episodes_between_training} episodes, {hp.loss_type} value loss, "
        f"stops after {hp.term_cond_max_episodes} policy updates",
    ]
    lines.append(f"race: {race_line(run.env.race)}")
    for k, worker in enumerate(run.worker_envs):
        lines.append(f"worker {k + 1}: {worker.describe()}")
    lines += notes
    lines += drfc_lines(drfc)
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
