"""``racer bench oa``: learn DeepRacer's object avoidance (or head-to-bot) from scratch and time it.

For each seed, one after the other: ``racer train`` (embedded Redis, 2 workers, the evaluator beside the trainer)
for a fixed budget on racer_loop (racer's default track) with the STEREO_CAMERAS sensor, the shipped
``object_avoidance`` reward example and a 10-action space for driving round objects (:data:`OA_ACTIONS`: five
steering angles from -30° to 30° at 1 and 2 m/s), racer's stability knobs on as in ``racer bench race``,
without its pace rule (:data:`racer.bench.race.GUARD_HYPERPARAMS`).

The race (:func:`oa_race`): OBJECT_AVOIDANCE with 3 boxes placed at random every episode
(``randomize_obstacle_locations``), or, with ``race_type`` HEAD_TO_BOT, 2 bot cars at 0.5 m/s starting at random
places and lanes every episode (``randomize_bot_car_locations``; no lane changes). The evaluator builds its envs from
the run's config, race included, so each of its trials draws its own box (or bot) placement from the trial's seed:
the 10 trials of one evaluation see 10 placements, and every checkpoint is judged on the same 10 (the evaluation seed
is fixed), so the curve compares like with like. It drives 10 start points spread round the lap, in the track's
direction, with 10 % action noise; a crash ends a trial (no resets).

The figures, per seed and their medians:

* ``time_to_robust_s``: when the first checkpoint that completed all of at least :data:`MIN_TRIALS` evaluation trials
  was made (null if none did), and ``env_steps_to_robust``;
* ``final_completion``: the completion (0-1) of the last evaluated checkpoint; ``final_crash_rate``: its share of
  trials that ended ``crashed``;
* ``curve``: per evaluated checkpoint, the time it was made, env steps, completion, crash rate, off-track rate and mean
  progress: the crash rate over time.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console

from common.defaults import DEFAULT_TRACK
from common.race import HeadToBotConfig, ObjectAvoidanceConfig, RaceConfig, RaceType
from common.sensors import STEREO_CAMERAS
from model_store import RunStore
from racer.bench import Report
from racer.bench.race import GUARD_HYPERPARAMS, median_known, train_from_scratch
from racer.runconfig import build_run
from sim.reward import example_path
from sim.task import Status

OA_ACTIONS = [
    {"steering_angle": steer, "speed": speed} for speed in (1.0, 2.0) for steer in (-30.0, -15.0, 0.0, 15.0, 30.0)
]
"""Five steering angles (±30°, ±15°, 0°) at 1 and 2 m/s: full lock for going round a box, and no more speed than a
camera at 15 Hz can react to (a box 1 m ahead is 7 steps away at 2 m/s)."""
OA_SENSORS = [STEREO_CAMERAS]
OA_HYPERPARAMS = GUARD_HYPERPARAMS
"""The stability knobs of ``racer bench race`` without its pace rule (``collapse_slowdown``), with which the
object-avoidance figures were measured: the rule has not been measured on a race round boxes."""
OA_REWARD = "object_avoidance"
"""The shipped reward example (``sim/reward_examples/object_avoidance.py``)."""
BOXES = 3
BOTS, BOT_SPEED = 2, 0.5
MIN_TRIALS = 10
"""A checkpoint counts as robust when it completes every one of at least this many evaluation trials."""


@dataclass(kw_only=True)
class BenchOASettings:
    """What ``racer bench oa`` runs."""

    seeds: list[int] = field(default_factory=lambda: [0])
    minutes: float = 60.0
    race_type: str = RaceType.OBJECT_AVOIDANCE.value
    """OBJECT_AVOIDANCE (3 random boxes) or HEAD_TO_BOT (2 bots at 0.5 m/s)."""
    track: str = DEFAULT_TRACK
    workers: int = 2
    eval_trials: int = MIN_TRIALS
    """Evaluation start points (the track's direction only), each with its own object placement."""


def oa_race(race_type: str | RaceType) -> RaceConfig:
    """The benchmark's race: :data:`BOXES` boxes placed at random every episode, or :data:`BOTS` bot cars at
    :data:`BOT_SPEED` m/s starting at random every episode; ValueError for a time trial."""
    kind = RaceType(str(race_type).upper())
    if kind is RaceType.OBJECT_AVOIDANCE:
        oa = ObjectAvoidanceConfig(number_of_obstacles=BOXES, randomize_obstacle_locations=True)
        return RaceConfig(race_type=kind, object_avoidance=oa)
    if kind is RaceType.HEAD_TO_BOT:
        h2b = HeadToBotConfig(number_of_bot_cars=BOTS, bot_car_speed=BOT_SPEED, randomize_bot_car_locations=True)
        return RaceConfig(race_type=kind, head_to_bot=h2b)
    raise ValueError(f"racer bench oa races OBJECT_AVOIDANCE or HEAD_TO_BOT, not {kind.value}")


def _files(folder: Path) -> tuple[Path, Path]:
    space, hp = folder / "model_metadata.json", folder / "hyperparameters.json"
    space.write_text(
        json.dumps({"action_space": OA_ACTIONS, "action_space_type": "discrete", "sensor": OA_SENSORS, "version": "5"})
    )
    hp.write_text(json.dumps(OA_HYPERPARAMS))
    return space, hp


def checkpoint_point(record: dict, time_s: float, env_steps: int) -> dict:
    """One point of the curve from an evaluation record (its ``trials`` hold each trial's ``status``)."""
    trials = record.get("trials") or []
    n = len(trials) or int(record.get("episodes") or 0)
    statuses = [t.get("status") for t in trials]
    return {
        "version": int(record["version"]),
        "time_s": round(time_s, 1),
        "env_steps": env_steps,
        "trials": n,
        "completion": float(record["completion_rate"]),
        "crash_rate": statuses.count(Status.CRASHED) / n if n else 0.0,
        "off_track_rate": statuses.count(Status.OFF_TRACK) / n if n else 0.0,
        "mean_progress": float(record.get("mean_progress") or 0.0),
    }


def oa_curve(run_id: str, runs: RunStore, t0: float) -> list[dict]:
    """Per evaluated checkpoint, in version order: :func:`checkpoint_point` with the time it was made (s from
    ``t0``) and its env steps."""
    made = {
        int(r["policy_version"]): (float(r["time"]) - t0, int(r["env_steps"]))
        for r in runs.read_metrics(run_id, missing_ok=True)
    }
    return [
        checkpoint_point(record, *made[int(record["version"])])
        for record in runs.read_evaluations(run_id)
        if int(record["version"]) in made
    ]


def seed_figures(curve: list[dict], min_trials: int = MIN_TRIALS) -> dict[str, Any]:
    """The per-seed figures of the module doc from a curve (:func:`checkpoint_point` rows in version order)."""
    robust = next((p for p in curve if p["completion"] >= 1.0 and p["trials"] >= min_trials), None)
    last = curve[-1] if curve else None
    return {
        "time_to_robust_s": robust["time_s"] if robust else None,
        "env_steps_to_robust": robust["env_steps"] if robust else None,
        "final_completion": last["completion"] if last else 0.0,
        "final_crash_rate": last["crash_rate"] if last else None,
        "best_completion": max((p["completion"] for p in curve), default=0.0),
        "checkpoints": len(curve),
    }


def run_seed(settings: BenchOASettings, seed: int) -> dict[str, Any]:
    """One seed: ``racer train`` for the budget, then its figures."""
    race = oa_race(settings.race_type)
    with tempfile.TemporaryDirectory(prefix="racer-bench-oa-") as tmp:
        space, hp = _files(Path(tmp))
        run_id = f"bench-oa-{race.race_type.value.lower().replace('_', '-')}-s{seed}"
        reward = str(example_path(OA_REWARD))
        run, files = build_run(
            run_id,
            track=settings.track,
            reward_fn=reward,
            action_space=str(space),
            hyperparams=str(hp),
            seed=seed,
            race=race,
        )
    curve, guard = train_from_scratch(
        run,
        files,
        workers=settings.workers,
        minutes=settings.minutes,
        eval_episodes=settings.eval_trials,
        read_curve=oa_curve,
    )
    figures = seed_figures(curve, min(MIN_TRIALS, settings.eval_trials))
    figures.update(seed=seed, rollbacks=guard["rollbacks"], curve=curve)
    return figures


def summarize(settings: BenchOASettings, seeds: list[dict[str, Any]]) -> dict[str, Any]:
    """The benchmark's result: its settings, the medians over the seeds and each seed's figures."""
    race = oa_race(settings.race_type)
    keys = ("time_to_robust_s", "env_steps_to_robust", "final_completion", "final_crash_rate")
    return {
        "race_type": race.race_type.value,
        "race": race.model_dump(mode="json"),
        "track": settings.track,
        "minutes": settings.minutes,
        "workers": settings.workers,
        "eval_trials": settings.eval_trials,
        "sensor": OA_SENSORS,
        "reward": OA_REWARD,
        "action_space": OA_ACTIONS,
        "hyperparams": OA_HYPERPARAMS,
        **{key: median_known([s[key] for s in seeds]) for key in keys},
        "robust_seeds": sum(s["time_to_robust_s"] is not None for s in seeds),
        "seeds": seeds,
    }


def bench_oa(settings: BenchOASettings, progress: Console | None = None) -> dict[str, Any]:
    """Every seed in turn, then medians; see the module doc."""
    oa_race(settings.race_type)  # a bad race type fails before any training
    seeds = []
    for seed in settings.seeds:
        figures = run_seed(settings, seed)
        seeds.append(figures)
        if progress:
            crash = figures["final_crash_rate"]
            progress.print(
                f"seed {seed}: robust after {figures['time_to_robust_s']} s, final completion "
                f"{figures['final_completion']:.2f}, final crash rate {'-' if crash is None else f'{crash:.2f}'}",
                highlight=False,
            )
    return summarize(settings, seeds)


def plot_oa(result: dict[str, Any], out_png: str | Path) -> Path:
    """Each seed's evaluation completion and crash rate against training time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from racer.plots import save_figure

    fig, (ax_done, ax_crash) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for s in result["seeds"]:
        t = [p["time_s"] / 60 for p in s["curve"]]
        ax_done.plot(t, [p["completion"] for p in s["curve"]], marker=".", label=f"seed {s['seed']}")
        ax_crash.plot(t, [p["crash_rate"] for p in s["curve"]], marker=".", label=f"seed {s['seed']}")
        if s["time_to_robust_s"] is not None:
            ax_done.axvline(s["time_to_robust_s"] / 60, color="grey", ls=":")
    for ax, label in ((ax_done, "evaluation completion"), (ax_crash, "crash rate (share of trials)")):
        ax.set_ylabel(label)
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
    ax_done.legend()
    ax_crash.set_xlabel("minutes")
    ax_done.set_title(
        f"racer bench oa: {result['race_type']} on {result['track']}, {', '.join(result['sensor'])}, "
        f"{result['minutes']:g} min per seed"
    )
    return save_figure(fig, out_png)


def command(
    race_type: str,
    seeds: list[int],
    minutes: float,
    *,
    track: str,
    workers: int,
    eval_trials: int,
    png: Path | None = None,
    progress: Console | None = None,
) -> Report:
    """``racer bench oa``: check the race and the track before any training, run the seeds, plot them to ``png``
    if given and report the time to robust and the crash rate."""
    from common.errors import OptionError
    from sim.track import load_track

    try:
        race = oa_race(race_type)
    except ValueError:
        raise OptionError(f"--race-type {race_type!r}: racer bench oa races OBJECT_AVOIDANCE or HEAD_TO_BOT") from None
    load_track(track)  # a bad track fails now, not after the first seed's training
    settings = BenchOASettings(
        seeds=seeds,
        minutes=minutes,
        race_type=race.race_type.value,
        track=track,
        workers=workers,
        eval_trials=eval_trials,
    )
    result = bench_oa(settings, progress)
    if png:
        plot_oa(result, png)
    crash = result["final_crash_rate"]
    line = (
        f"{result['race_type']}: median time to robust {result['time_to_robust_s']} s "
        f"({result['robust_seeds']} of {len(result['seeds'])} seeds robust), final completion "
        f"{result['final_completion']:.2f}, final crash rate {'-' if crash is None else f'{crash:.2f}'}"
    )
    return Report(result, [line])
