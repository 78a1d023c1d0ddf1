"""``racer bench race``: learn to race from scratch and set the result beside the car's lap-time limit.

For each seed, one after the other: ``racer train`` (embedded Redis, 2 workers, the evaluator beside the trainer)
for a fixed budget on a 4 m/s action space (:data:`RACE_ACTIONS`, or a user's, discrete or continuous:
``--action-space``) with the racing reward example, racer's stability knobs on (the collapse guard with its pace
rule, and target-KL early stopping: :data:`RACE_HYPERPARAMS`; a continuous space's checkpoints act on the mean of
their clipped action: :data:`CONTINUOUS_HYPERPARAMS`). The evaluator judges every checkpoint on 10 start
points spread round the lap, in the track's direction as a DeepRacer race is driven, with 10 % action noise. The
figures:

* ``time_to_robust_s``: when the first checkpoint that completed all its evaluation laps was made;
* ``best_robust_lap_s``: the lowest mean lap time of such a checkpoint (every trial a lap, standing starts);
* ``limit_s`` and ``ratio_to_limit``: ``racer limit`` for the same car, track and action space (its
  ``best_known_lap_s``: the computed limit, or the controller's driven lap where that beat it);
* ``collapses``: checkpoints after the first robust one whose completion fell below 50 %, and
  ``collapses_recovered`` those followed later by a robust checkpoint; ``rollbacks``: the collapse guard's, and
  ``slow_rollbacks``: those of them its ``collapse_slowdown`` started;
* ``final_completion``: the completion of the last evaluated checkpoint (0-1);
* ``late_robust_lap_s``: the median mean lap of the robust checkpoints made in the budget's last fifth (where the
  learner ended up, not its luckiest checkpoint), and ``drift_after_best``: that over ``best_robust_lap_s`` (1.0:
  it held its best; 1.2: it ended 20 % slower; None where no late checkpoint was robust);
* ``best_command_speeds``: the share of the steps of the best robust checkpoint's evaluation laps at each commanded
  speed (``{"1.5": 1.0}``: it drove every step at the slowest action; for a continuous space the speeds are counted
  in :data:`SPEED_BIN_MPS` bins, keyed by the bin's lower edge). Each point of a seed's curve has its own
  ``command_speeds``. A policy that settles on its slowest actions completes laps and stops getting faster
  (docs/racing.md); this says so without a simtrace.

The medians are over the seeds that reached each figure; ``robust_seeds`` says how many lapped robustly at all.

The reward example's constants are set to the car, as its header asks a user to do (``reward_constants``: from the
limits ``racer limit`` measured), and the JSON records them under ``reward_constants``.
"""

from __future__ import annotations

import io
import json
import math
import re
import statistics
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

from rich.console import Console

from common.car_calibration import load_car
from common.config import RandomizationConfig, RunConfig
from common.defaults import DEFAULT_TRACK
from common.errors import OptionError
from common.jsonfile import read_json_object
from model_store import LocalStore, RunStore
from racer.bench import Report
from racer.embedded_redis import EmbeddedRedis
from racer.launcher import run_train
from racer.options import RunOptions
from racer.runconfig import build_run, load_randomization
from sim.reward import example_path

RACE_ACTIONS = [
    {"steering_angle": steer, "speed": speed} for speed in (1.5, 2.75, 4.0) for steer in (-30.0, -15.0, 0.0, 15.0, 30.0)
]
"""A 4 m/s discrete action space: five steering angles at three speeds."""
RaceActions = list[dict[str, float]] | dict[str, dict[str, float]]
"""A DeepRacer ``action_space`` as model_metadata.json writes it: a discrete space's list of ``{"steering_angle",
"speed"}`` actions, or a continuous space's ``{"steering_angle": {"low", "high"}, "speed": {"low", "high"}}``."""
SPEED_BIN_MPS = 0.25
"""Width of the speed bins ``command_speeds`` counts a continuous space's commands in, m/s."""
GUARD_HYPERPARAMS = {"collapse_guard": True, "collapse_min_best": 0.9, "target_kl": 0.05}
"""DeepRacer's defaults plus racer's stability knobs; learning rate and entropy constant, as in DeepRacer. The guard
acts only once a checkpoint has been (nearly) robust: in a first 15-minute run it acted from a best of 0.6 of 10
trials, where completion is still noise, and rolled one seed back 7 times, halving the learning rate each time
until learning stopped. Learning-rate and entropy schedules were no faster (docs/racing.md, "What did not help"),
so they are not the bench's default. ``racer bench oa`` uses these as they are."""
RACE_HYPERPARAMS = {**GUARD_HYPERPARAMS, "collapse_slowdown": 0.15}
""":data:`GUARD_HYPERPARAMS` and the guard's pace rule: a checkpoint whose robust laps are more than 15 % slower than
the best's counts as collapsed too, so that a seed that drifts to slower laps after its best is rolled back rather
than ending there (the figures with and without it: docs/racing.md)."""
CONTINUOUS_HYPERPARAMS = {"greedy_action": "expected"}
"""Laid over :data:`RACE_HYPERPARAMS` for a continuous action space: its checkpoints are judged on the mean of their
clipped action, not on their Gaussian's mean (``Hyperparameters.greedy_action``; ``{"greedy_action": "mean"}``
restores DeepRacer's). The Gazebo car's Gaussians kept half the range as their spread and their speed means drifted
below the range, so the evaluator drove 1.5 m/s where training had driven the spread above it (docs/racing.md)."""
REWARD_SHARE_OF_LIMIT = 0.8
"""The reward example's LATERAL_ACCEL and BRAKE are this share of the car's measured figures: a line's target
speeds a little inside what the car holds, as the example's default (5 m/s² for a car measured at ~6.7) is."""
COLLAPSED_BELOW = 0.5
"""A checkpoint after the first robust one whose completion falls below this is a collapse."""
LATE_SHARE = 0.2
"""``late_robust_lap_s`` reads the robust checkpoints made in this last share of the budget. A seed's best can be
one lucky checkpoint early in the run, so the bench also says where each seed ended."""


@dataclass(kw_only=True)
class BenchRaceSettings:
    """What ``racer bench race`` runs."""

    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    minutes: float = 30.0
    track: str = DEFAULT_TRACK
    car: str = "default"
    workers: int = 2
    eval_starts: int = 10
    """Evaluation start points (the track's direction only)."""
    hyperparams: dict[str, Any] = field(default_factory=dict)
    """A user's hyperparameters laid over :data:`RACE_HYPERPARAMS` (``--hyperparams F``: ``{"stack_size": 3}``)."""
    reward_constants: dict[str, float] = field(default_factory=dict)
    """A user's values of the racing example's constants laid over those set to the car (``--reward-constants F``:
    ``{"MARGIN": 0.25}``); checked by :func:`load_reward_constants`."""
    randomization: str | None = None
    """A domain-randomization file the rollout workers train with (``--randomization F``: ``{"action_noise":
    0.1}``, the noise racer's evaluator drives with); None: racer's defaults, no randomization but random starts."""
    actions: RaceActions | None = None
    """A user's action space (``--action-space F``, read by :func:`load_race_actions`); None: :data:`RACE_ACTIONS`.
    The limit, the reward example's ``MAX_SPEED`` and the seeds all use it."""
    teacher: bool = False
    """``--teacher``: each seed also trains with a privileged teacher (``racer train --teacher``: the teacher for a
    third of the budget, then its student), in the same invocation after the plain run of that seed."""

    def race_actions(self) -> RaceActions:
        """The action space the seeds train with and the limit is computed for."""
        return RACE_ACTIONS if self.actions is None else self.actions

    def race_hyperparams(self) -> dict[str, Any]:
        """What the seeds train with: :data:`RACE_HYPERPARAMS` and the user's keys over them. A user who turns the
        collapse guard off (``{"collapse_guard": false}``: DeepRacer's behaviour) gets none of the bench's guard
        settings: they would change nothing, and the run's hyperparameters would list them as idle."""
        bench = RACE_HYPERPARAMS
        if self.hyperparams.get("collapse_guard") is False:
            bench = {k: v for k, v in bench.items() if not k.startswith("collapse_")}
        if is_continuous(self.race_actions()):
            bench = {**bench, **CONTINUOUS_HYPERPARAMS}
        return {**bench, **self.hyperparams}


def is_continuous(actions: RaceActions) -> bool:
    """Whether ``actions`` is a continuous space's ranges (DeepRacer tells the two apart by the value's shape too)."""
    return isinstance(actions, dict)


def top_speed(actions: RaceActions) -> float:
    """The highest speed an action space commands, m/s."""
    if is_continuous(actions):
        return float(actions["speed"]["high"])  # type: ignore[call-overload]
    return max(float(a["speed"]) for a in actions)  # type: ignore[union-attr]


def reward_constants(car_limits: dict[str, Any], actions: RaceActions = RACE_ACTIONS) -> dict[str, float]:
    """The racing example's MAX_SPEED, LATERAL_ACCEL and BRAKE for a car (``racer limit``'s ``car_limits``): the
    action space's top speed (``actions``), and :data:`REWARD_SHARE_OF_LIMIT` of
    the median lateral acceleration the car holds from 2 m/s up and of its median braking from 1 m/s up. Without
    this the Gazebo car (3.2 m/s² of lateral grip) was asked for the default car's bend speeds, and one seed never
    lapped robustly in 30 minutes."""
    speeds = car_limits["speeds"]
    lateral = [a for v, a in zip(speeds, car_limits["max_lateral_accel"], strict=True) if v >= 2.0]
    brake = [b for v, b in zip(speeds, car_limits["brake"], strict=True) if v >= 1.0]
    return {
        "MAX_SPEED": top_speed(actions),
        "LATERAL_ACCEL": round(REWARD_SHARE_OF_LIMIT * statistics.median(lateral), 2),
        "BRAKE": round(REWARD_SHARE_OF_LIMIT * statistics.median(brake), 2),
    }


_CONSTANT_LINE = r"^({name}) = ([0-9.]+)"
"""How the racing example spells a constant: ``NAME = number`` at the start of a line; read and set only with it."""


def example_constants() -> dict[str, float]:
    """The racing example's constants and their shipped values (integers where the example writes one)."""
    text = example_path("racing_line").read_text()
    found = re.finditer(_CONSTANT_LINE.format(name="[A-Z_]+"), text, flags=re.M)
    return {m[1]: float(m[2]) if "." in m[2] else int(m[2]) for m in found}


def load_reward_constants(path: str | Path) -> dict[str, float]:
    """A JSON object of the racing example's constants and positive numbers (``{"MARGIN": 0.25}``); otherwise
    :class:`OptionError` naming the file, the key and the bad value."""
    data = read_json_object(path, "reward constants file", OptionError)
    known = example_constants()
    for key, value in data.items():
        if key not in known:
            raise OptionError(
                f"reward constants file {str(path)!r}: {key!r} is not a constant of the racing example "
                f"(one of {', '.join(sorted(known))})"
            )
        kind = "a positive integer" if isinstance(known[key], int) else "a positive number"
        allowed = int if isinstance(known[key], int) else int | float
        if isinstance(value, bool) or not isinstance(value, allowed) or not value > 0:
            raise OptionError(f"reward constants file {str(path)!r}: {key}: expected {kind}, got {value!r}")
    return dict(data)


def reward_file(folder: Path, constants: dict[str, float]) -> Path:
    """A copy of the racing example with its constants set (what a user does by hand), in ``folder``."""
    text = example_path("racing_line").read_text()
    for name, value in constants.items():
        pattern = _CONSTANT_LINE.format(name=re.escape(name))
        text, found = re.subn(pattern, f"{name} = {value}", text, count=1, flags=re.M)
        if not found:
            raise ValueError(f"{example_path('racing_line')}: no constant {name} to set")
    path = folder / "reward_function.py"
    path.write_text(text)
    return path


def load_race_actions(path: str | Path) -> RaceActions:
    """A DeepRacer model_metadata.json's ``action_space`` (:data:`RaceActions`: a discrete space's actions or a
    continuous space's ranges); :class:`ActionSpaceError` naming the file where it asks for more than actions."""
    from common.action_space import ActionSpace, ActionSpaceError, load_action_space

    space = load_action_space(path)
    bench = ActionSpace(action_space_type=space.action_space_type, action_space=space.action_space)
    for key in ("sensor", "neural_network"):  # the bench trains only the actions; say so rather than drop the rest
        if getattr(space, key) != getattr(bench, key):
            raise ActionSpaceError(
                f"action space file {str(path)!r}: {key}: racer bench race trains {getattr(bench, key)!r} and takes "
                f"only the actions from this file, got {getattr(space, key)!r}"
            )
    if space.discrete:
        return [{"steering_angle": a.steering_angle, "speed": a.speed} for a in space.action_space]  # type: ignore[union-attr]
    return space.action_space.model_dump()  # type: ignore[union-attr]


def _files(
    folder: Path, hyperparams: dict[str, Any] | None = None, actions: RaceActions = RACE_ACTIONS
) -> tuple[Path, Path]:
    space, hp = folder / "model_metadata.json", folder / "hyperparameters.json"
    kind = "continuous" if is_continuous(actions) else "discrete"
    space.write_text(json.dumps({"action_space": actions, "action_space_type": kind}))
    hp.write_text(json.dumps(RACE_HYPERPARAMS if hyperparams is None else hyperparams))
    return space, hp


def race_curve(run_id: str, runs: RunStore, t0: float, speed_bin: float | None = None) -> list[dict]:
    """Per evaluated checkpoint, in version order: version, time made (s from ``t0``), env steps, completion,
    mean and best lap (s), and ``command_speeds`` (in ``speed_bin`` bins where given: a continuous space).

    Only checkpoints a training update made: the time comes from the trainer's metrics rows, and a collapse-guard
    rollback writes none, so its republished copy of the best is left out (it is the best again, not a policy the
    learner reached, and must not count as a recovery or as the final checkpoint)."""
    made = {
        int(r["policy_version"]): (float(r["time"]) - t0, int(r["env_steps"]))
        for r in runs.read_metrics(run_id, missing_ok=True)
    }
    curve = []
    for record in runs.read_evaluations(run_id):
        version = int(record["version"])
        if version not in made:
            continue
        laps = record.get("lap_times_s") or []
        curve.append(
            {
                "version": version,
                "time_s": round(made[version][0], 1),
                "env_steps": made[version][1],
                "completion": float(record["completion_rate"]),
                "mean_lap_s": statistics.fmean(laps) if laps else None,
                "best_lap_s": min(laps) if laps else None,
                "command_speeds": command_speeds(record, speed_bin),
            }
        )
    return curve


def command_speeds(record: dict, speed_bin: float | None = None) -> dict[str, float]:
    """The share of an evaluation's steps, over all its trials, at each commanded speed (the third field of each
    trajectory point, the action's speed as the reward function's ``params['speed']`` sees it), keyed by the speed
    as text in ascending order; empty where the record has no trajectories. With ``speed_bin`` (a continuous
    space's speeds, all different) each speed counts in its bin, keyed by the bin's lower edge."""
    speeds = (float(point[2]) for trial in record.get("trials") or [] for point in trial.get("trajectory") or [])
    if speed_bin:
        # The small tolerance keeps a speed on a bin's edge in that bin where the division rounds below it (0.3 / 0.1
        # is 2.9999999999999996); 0.25 m/s edges divide exactly.
        speeds = (math.floor(v / speed_bin + 1e-9) * speed_bin for v in speeds)
    counts = Counter(speeds)
    total = sum(counts.values())
    return {f"{speed:g}": counts[speed] / total for speed in sorted(counts)}


def seed_figures(curve: list[dict], limit_s: float, budget_s: float | None = None) -> dict[str, Any]:
    """The per-seed figures of the module doc from an evaluation curve; ``budget_s`` (the training budget) places
    the late window, which ends at the last checkpoint where it is not given."""
    robust = [p for p in curve if p["completion"] >= 1.0]
    first = robust[0] if robust else None
    best_point = min(robust, key=lambda p: p["mean_lap_s"], default=None)
    best = None if best_point is None else best_point["mean_lap_s"]
    after = [p for p in curve if first is not None and p["version"] > first["version"]]
    collapsed = [i for i, p in enumerate(after) if p["completion"] < COLLAPSED_BELOW]
    starts = [i for i in collapsed if i == 0 or after[i - 1]["completion"] >= COLLAPSED_BELOW]
    recovered = [i for i in starts if any(p["completion"] >= 1.0 for p in after[i:])]
    late = late_robust_lap(curve, budget_s)
    return {
        "time_to_robust_s": first["time_s"] if first else None,
        "env_steps_to_robust": first["env_steps"] if first else None,
        "best_robust_lap_s": best,
        "limit_s": limit_s,
        "ratio_to_limit": None if best is None else best / limit_s,
        "collapses": len(starts),
        "collapses_recovered": len(recovered),
        "final_completion": curve[-1]["completion"] if curve else 0.0,
        "late_robust_lap_s": late,
        "drift_after_best": None if late is None or best is None else late / best,
        "best_command_speeds": None if best_point is None else best_point.get("command_speeds"),
        "ratio_at_minutes": ratio_at_minutes(curve, limit_s, budget_s),
    }


CHECKPOINT_MINUTES = (5, 10, 30)
"""The times the best robust lap so far is read at (``ratio_at_minutes``), minutes into the budget."""


def ratio_at_minutes(curve: list[dict], limit_s: float, budget_s: float | None = None) -> dict[str, float | None]:
    """The best robust lap of the checkpoints made in the first 5, 10 and 30 minutes over ``limit_s``, for each of
    those times within ``budget_s`` (the curve's span where it is not given); None where none was robust yet."""
    end = budget_s if budget_s is not None else (curve[-1]["time_s"] if curve else 0.0)
    out: dict[str, float | None] = {}
    for minutes in CHECKPOINT_MINUTES:
        if minutes * 60.0 > end + 1e-6:
            continue
        laps = [p["mean_lap_s"] for p in curve if p["completion"] >= 1.0 and p["time_s"] <= minutes * 60.0]
        out[str(minutes)] = min(laps) / limit_s if laps else None
    return out


def late_robust_lap(curve: list[dict], budget_s: float | None = None) -> float | None:
    """The median mean lap of the robust checkpoints made in the last :data:`LATE_SHARE` of ``budget_s`` (of the
    curve's span where it is not given); None if none of them is robust."""
    if not curve:
        return None
    end = budget_s if budget_s is not None else curve[-1]["time_s"]
    laps = [p["mean_lap_s"] for p in curve if p["time_s"] >= (1.0 - LATE_SHARE) * end and p["completion"] >= 1.0]
    return statistics.median(laps) if laps else None


def train_from_scratch(
    run: RunConfig,
    files: dict[str, bytes],
    *,
    workers: int,
    minutes: float,
    eval_episodes: int,
    read_curve: Callable[[str, RunStore, float], list[dict]],
    store_dir: Path | None = None,
) -> tuple[list[dict], dict[str, int]]:
    """``racer train`` (embedded Redis, the evaluator beside the trainer evaluating every checkpoint from
    ``eval_episodes`` starts in the track's direction) for ``minutes`` in a throwaway store (or in ``store_dir``,
    kept for the caller); then ``read_curve(run_id, runs, t0)`` of the stored run and the collapse guard's
    ``rollbacks`` and ``slow_rollbacks`` (those its ``collapse_slowdown`` started). ``racer bench race``, ``bench
    oa`` and ``bench transfer`` share it."""
    with EmbeddedRedis() as server, tempfile.TemporaryDirectory(prefix="racer-bench-") as tmp:
        store = store_dir or Path(tmp, "store")
        opts = bench_options(server.url, store, workers=workers, minutes=minutes, eval_episodes=eval_episodes)
        t0 = time.time()
        run_train(run, opts, files, Console(file=io.StringIO()))
        runs = RunStore(LocalStore(store))
        return read_curve(run.run_id, runs, t0), guard_counts(runs, run.run_id)


def bench_options(redis_url: str, store: Path, *, workers: int, minutes: float, eval_episodes: int) -> RunOptions:
    """A bench run's options: ``workers``, a time limit of ``minutes``, every checkpoint evaluated from
    ``eval_episodes`` starts in the track's direction."""
    return RunOptions(
        workers=workers,
        redis_url=redis_url,
        store=str(store),
        time_limit_s=minutes * 60.0,
        eval_every=1,
        eval_episodes=eval_episodes,
        eval_both_directions=False,
    )


def guard_counts(runs: RunStore, run_id: str) -> dict[str, int]:
    """The collapse guard's ``rollbacks`` and ``slow_rollbacks`` of a stored run (its last metrics row)."""
    rows = runs.read_metrics(run_id, missing_ok=True)
    last = rows[-1] if rows else {}
    return {key: int(last.get(key, 0)) for key in ("rollbacks", "slow_rollbacks")}


def train_teacher_student(
    run: RunConfig,
    files: dict[str, bytes],
    *,
    workers: int,
    minutes: float,
    eval_episodes: int,
    read_curve: Callable[[str, RunStore, float], list[dict]],
) -> tuple[list[dict], list[dict], dict[str, int]]:
    """``racer train --teacher`` for ``minutes`` in all (the teacher a third of them: ``racer.teacher``), as
    :func:`train_from_scratch` trains; the student's curve and the teacher's, both timed from the teacher's start,
    and the student's guard counts."""
    from racer.teacher import TEACHER_SUFFIX, split_time, train_with_teacher

    with EmbeddedRedis() as server, tempfile.TemporaryDirectory(prefix="racer-bench-") as tmp:
        store = Path(tmp, "store")
        opts = bench_options(server.url, store, workers=workers, minutes=minutes, eval_episodes=eval_episodes)
        runs = RunStore(LocalStore(store))
        t0 = time.time()
        train_with_teacher(
            runs,
            opts.model_copy(update={"run_id": run.run_id}),
            (run, files),
            distill={},
            teacher_time_s=split_time(opts, None),
            console=Console(file=io.StringIO()),
        )
        teacher = read_curve(run.run_id + TEACHER_SUFFIX, runs, t0)
        return read_curve(run.run_id, runs, t0), teacher, guard_counts(runs, run.run_id)


def seed_run(settings: BenchRaceSettings, seed: int, constants: dict[str, float]) -> tuple[RunConfig, dict[str, bytes]]:
    """One seed's run and files: the bench's action space and hyperparameters, the racing example with
    ``constants``, the settings' car and randomization."""
    with tempfile.TemporaryDirectory(prefix="racer-bench-race-") as tmp:
        space, hp = _files(Path(tmp), settings.race_hyperparams(), settings.race_actions())
        reward = str(reward_file(Path(tmp), constants))
        run, files = build_run(
            f"bench-race-s{seed}",
            track=settings.track,
            reward_fn=reward,
            action_space=str(space),
            hyperparams=str(hp),
            randomization=settings.randomization,
            seed=seed,
        )
    return run.model_copy(update={"env": run.env.model_copy(update={"car": load_car(settings.car)})}), files


def run_seed(
    settings: BenchRaceSettings, seed: int, limit_s: float, constants: dict[str, float], *, teacher: bool = False
) -> dict[str, Any]:
    """One seed: ``racer train`` for the budget (with ``teacher``, ``racer train --teacher``), then its figures;
    with a teacher also the teacher's own (``teacher``) and the student's gap to it (``student_gap``: the student's
    best robust lap over the teacher's)."""
    run, files = seed_run(settings, seed, constants)
    actions = settings.race_actions()
    read_curve = partial(race_curve, speed_bin=SPEED_BIN_MPS) if is_continuous(actions) else race_curve
    budget = {"workers": settings.workers, "minutes": settings.minutes, "eval_episodes": settings.eval_starts}
    if not teacher:
        curve, guard = train_from_scratch(run, files, **budget, read_curve=read_curve)
        return {**seed_figures(curve, limit_s, settings.minutes * 60.0), "seed": seed, **guard, "curve": curve}
    curve, teacher_curve, guard = train_teacher_student(run, files, **budget, read_curve=read_curve)
    figures = {**seed_figures(curve, limit_s, settings.minutes * 60.0), "seed": seed, **guard, "curve": curve}
    own = seed_figures(teacher_curve, limit_s)
    own["env_steps"] = teacher_curve[-1]["env_steps"] if teacher_curve else 0  # the state steps it learnt from
    student, best = figures["best_robust_lap_s"], own["best_robust_lap_s"]
    figures["teacher"] = {**own, "curve": teacher_curve}
    figures["student_gap"] = None if student is None or best is None else student / best
    return figures


def training_randomization(path: str | None) -> dict[str, Any]:
    """The domain randomization the seeds train with (racer's defaults where ``path`` is None), as the JSON
    records it."""
    return (load_randomization(path) if path else RandomizationConfig()).model_dump(mode="json")


def seconds_text(value: float | None) -> str:
    """A figure in seconds for the console, to the hundredth (a mean lap of 1/15 s steps prints as 12.019999999999957
    otherwise); ``-`` where a seed never reached it."""
    return "-" if value is None else f"{value:.2f} s"


def shares_text(shares: dict[str, float] | None) -> str:
    """``command_speeds`` for the console: each speed's share of the steps in per cent."""
    return "-" if not shares else ", ".join(f"{speed} m/s {share:.0%}" for speed, share in shares.items())


def median_known(values: list[float | None]) -> float | None:
    """The median of the values that are known (None: a seed that never reached the figure); None if none is. The
    result says how many seeds it is over (``robust_seeds``): with one seed of three never robust, this is the
    median of the other two, where counting that seed as the slowest would give the slower of them."""
    known = [v for v in values if v is not None]
    return statistics.median(known) if known else None


def bench_race(settings: BenchRaceSettings, progress: Console | None = None) -> dict[str, Any]:
    """Every seed in turn, then medians; see the module doc."""
    from racer.limit import compute_limit

    with tempfile.TemporaryDirectory() as tmp:
        space, _ = _files(Path(tmp), actions=settings.race_actions())
        limit = compute_limit(settings.track, settings.car, space)
    limit_s = float(limit["best_known_lap_s"])
    constants = {**reward_constants(limit["car_limits"], settings.race_actions()), **settings.reward_constants}
    if progress:
        progress.print(f"limit on {settings.track} for car {settings.car}: {limit_s:.2f} s", highlight=False)
        progress.print(f"reward example's constants for this car: {constants}", highlight=False)
    plain, taught = [], []
    for seed in settings.seeds:
        plain.append(run_seed(settings, seed, limit_s, constants))
        if progress:
            progress.print(f"seed {seed}: {seed_line(plain[-1])}", highlight=False)
        if settings.teacher:
            taught.append(run_seed(settings, seed, limit_s, constants, teacher=True))
            if progress:
                progress.print(f"seed {seed} with a teacher: {seed_line(taught[-1])}", highlight=False)
    result = {
        "track": settings.track,
        "car": settings.car,
        "minutes": settings.minutes,
        "workers": settings.workers,
        "eval_starts": settings.eval_starts,
        "action_space": settings.race_actions(),
        "hyperparams": settings.race_hyperparams(),
        "reward_constants": constants,
        "randomization": training_randomization(settings.randomization),
        "limit_s": limit_s,
        "computed_limit_s": limit["lap_time_s"],
        "driven_limit_s": limit["driven_lap_time_s"],
    }
    if not settings.teacher:
        return {**result, **seed_block(plain)}
    return {**result, "plain": seed_block(plain), "teacher": teacher_block(taught)}


SEED_MEDIANS = (
    "time_to_robust_s",
    "best_robust_lap_s",
    "ratio_to_limit",
    "final_completion",
    "late_robust_lap_s",
    "drift_after_best",
)
"""The per-seed figures a block gives the median of (over the seeds that reached each)."""


def seed_line(figures: dict[str, Any]) -> str:
    """One seed's figures for the console."""
    line = (
        f"robust after {seconds_text(figures['time_to_robust_s'])}, best robust lap "
        f"{seconds_text(figures['best_robust_lap_s'])}, collapses {figures['collapses']}, "
        f"final completion {figures['final_completion']:.2f}, "
        f"late robust lap {seconds_text(figures['late_robust_lap_s'])}, "
        f"the best's steps at each commanded speed: {shares_text(figures['best_command_speeds'])}"
    )
    if "teacher" in figures:
        line += f"; the teacher's best robust lap {seconds_text(figures['teacher']['best_robust_lap_s'])}"
    return line


def seed_block(seeds: list[dict[str, Any]]) -> dict[str, Any]:
    """The medians, sums and seeds of one kind of run (plain, or with a teacher); ``median_ratio_to_limit`` is
    ``ratio_to_limit`` (already the median) under the name ``--teacher``'s comparison reads."""
    medians = {key: median_known([s[key] for s in seeds]) for key in SEED_MEDIANS}
    at = sorted({m for s in seeds for m in s["ratio_at_minutes"]}, key=float)
    return {
        **medians,
        "median_ratio_to_limit": medians["ratio_to_limit"],
        "median_ratio_at_minutes": {m: median_known([s["ratio_at_minutes"].get(m) for s in seeds]) for m in at},
        "env_steps_to_robust": median_known([s["env_steps_to_robust"] for s in seeds]),
        "collapses": sum(s["collapses"] for s in seeds),
        "collapses_recovered": sum(s["collapses_recovered"] for s in seeds),
        "robust_seeds": sum(s["time_to_robust_s"] is not None for s in seeds),
        "seeds": seeds,
    }


def teacher_block(seeds: list[dict[str, Any]]) -> dict[str, Any]:
    """``seed_block`` of the runs with a teacher, with the teachers' own median ratio to the limit and the
    students' median gap to their teachers (the student's best robust lap over the teacher's: what the camera
    does not see)."""
    return {
        **seed_block(seeds),
        "teacher_ratio_to_limit": median_known([s["teacher"]["ratio_to_limit"] for s in seeds]),
        "teacher_time_to_robust_s": median_known([s["teacher"]["time_to_robust_s"] for s in seeds]),
        "teacher_env_steps": median_known([s["teacher"]["env_steps"] for s in seeds]),
        "student_gap": median_known([s["student_gap"] for s in seeds]),
    }


def plot_race(result: dict[str, Any], out_png: str | Path) -> Path:
    """Learning curves: each seed's robust mean lap time (and completion) against time, the limit drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from racer.plots import save_figure

    fig, (ax_lap, ax_done) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    # Plain runs solid; with --teacher, the students dashed in their seed's colour (their time counts the teacher's).
    kinds = (
        [("", "-", result["plain"]["seeds"]), (" teacher", "--", result["teacher"]["seeds"])]
        if "plain" in result
        else [("", "-", result["seeds"])]
    )
    for suffix, style, seeds in kinds:
        for i, s in enumerate(seeds):
            # One colour a seed in both panels: a seed with no robust lap draws nothing in the upper one.
            label = f"seed {s['seed']}{suffix}"
            t = [p["time_s"] / 60 for p in s["curve"]]
            ax_done.plot(t, [p["completion"] for p in s["curve"]], ls=style, marker=".", color=f"C{i}", label=label)
            robust = [(p["time_s"] / 60, p["mean_lap_s"]) for p in s["curve"] if p["completion"] >= 1.0]
            if robust:
                ax_lap.plot(*zip(*robust, strict=True), ls=style, marker="o", color=f"C{i}", label=label)
    ax_lap.axhline(result["limit_s"], color="black", ls="--", label=f"racer limit {result['limit_s']:.2f} s")
    ax_lap.set_ylabel("robust mean lap (s)")
    ax_lap.legend()
    ax_done.legend(loc="lower right")
    ax_done.set_ylabel("evaluation completion")
    ax_done.set_xlabel("minutes")
    ax_done.set_ylim(-0.05, 1.05)
    ax_lap.set_title(f"racer bench race: {result['track']}, car {result['car']}, {result['minutes']:g} min per seed")
    return save_figure(fig, out_png)


@dataclass
class RaceFiles:
    """The user's files for ``racer bench race`` (each None: the bench's own)."""

    hyperparams: Path | None = None
    """A DeepRacer hyperparameters.json laid over :data:`RACE_HYPERPARAMS`."""
    reward_constants: Path | None = None
    """JSON of the racing example's constants over those set to the car."""
    randomization: Path | None = None
    """JSON of the domain randomization the workers train with."""
    action_space: Path | None = None
    """A model_metadata.json with a discrete or continuous action space."""


def command(
    seeds: list[int],
    minutes: float,
    track: str,
    *,
    car: str,
    workers: int,
    eval_starts: int,
    files: RaceFiles,
    png: Path | None = None,
    progress: Console | None = None,
    teacher: bool = False,
) -> Report:
    """``racer bench race``: check the car, track and the user's files before any training, run the seeds (with
    ``teacher``, each also with a teacher: ``BenchRaceSettings.teacher``), plot them to ``png`` if given and
    compare the best robust lap with the limit."""
    from common.hyperparams import HyperparametersError, load_hyperparameters
    from sim.track import load_track

    load_car(car)  # a bad car, track or hyperparameters file fails now, not after the first seed's training
    load_track(track)
    overrides = {}
    if files.hyperparams:
        load_hyperparameters(files.hyperparams)
        overrides = read_json_object(files.hyperparams, "hyperparameters file", HyperparametersError)
    constants = load_reward_constants(files.reward_constants) if files.reward_constants else {}
    if files.randomization:
        load_randomization(files.randomization)
    actions = load_race_actions(files.action_space) if files.action_space else None
    if overrides.get("greedy_action", "mean") != "mean" and not isinstance(actions, dict):
        # A discrete space acts by its argmax: refused now, naming the user's file, not after the limit has run.
        raise HyperparametersError(
            f"{files.hyperparams}: greedy_action {overrides['greedy_action']!r} applies to a continuous action "
            "space; the bench's is discrete"
        )
    randomization = str(files.randomization) if files.randomization else None
    settings = BenchRaceSettings(
        seeds=seeds,
        minutes=minutes,
        track=track,
        car=car,
        workers=workers,
        eval_starts=eval_starts,
        hyperparams=overrides,
        reward_constants=constants,
        randomization=randomization,
        actions=actions,
        teacher=teacher,
    )
    result = bench_race(settings, progress)
    if png:
        plot_race(result, png)
    if not teacher:
        return Report(result, [block_line(result, result["limit_s"])])
    lines = [f"plain: {block_line(result['plain'], result['limit_s'])}"]
    block = result["teacher"]
    gap = block["student_gap"]
    lines.append(
        f"with a teacher: {block_line(block, result['limit_s'])}; the teachers' own ratio to the limit "
        + ("-" if block["teacher_ratio_to_limit"] is None else f"{block['teacher_ratio_to_limit']:.2f} x")
        + ", the students' gap to them "
        + ("-" if gap is None else f"{gap:.2f} x")
    )
    return Report(result, lines)


def block_line(block: dict[str, Any], limit_s: float) -> str:
    """One block's medians for the console."""
    ratio = block["ratio_to_limit"]
    return (
        f"median best robust lap {seconds_text(block['best_robust_lap_s'])}, limit {limit_s:.2f} s"
        + (f" ({ratio:.2f} x)" if ratio else "")
        + f", robust after {seconds_text(block['time_to_robust_s'])}"
        + f", collapses {block['collapses']} ({block['collapses_recovered']} recovered)"
        + f", late robust lap {seconds_text(block['late_robust_lap_s'])}"
    )
