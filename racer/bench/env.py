"""``racer bench env``: env steps per second on one core, and where the time goes.

With a sensor list (``sensors``: a model_metadata.json ``sensor`` list, e.g. STEREO_CAMERAS and LIDAR) or a race
(``race``: object avoidance with boxes, head-to-bot with bot cars), the env is built with them and the result adds
``sensor``, ``race_type``, ``objects`` and the per-step cost of the LiDAR scan and of the objects (moving the bots,
placing them in the MuJoCo scene, the crash rule); without either, the result is today's, key for key.
"""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np
from rich.table import Table

from common.action_space import default_action_space, load_action_space
from common.config import EnvConfig
from common.race import HeadToBotConfig, ObjectAvoidanceConfig, RaceConfig, RaceType
from common.sensors import lidar_from_ranges, observation_spec
from racer.bench import Report
from sim.env import RacerEnv

DEFAULT_OBJECTS: dict[RaceType, int] = {RaceType.OBJECT_AVOIDANCE: 6, RaceType.HEAD_TO_BOT: 3}
"""Objects of a benchmarked race when no count is given: DRfC's 6 boxes, 3 bot cars."""


def race_config(race_type: str | RaceType, objects: int | None = None) -> RaceConfig:
    """The race of ``racer bench env --race-type T [--obstacles N]``: N boxes (object avoidance, evenly spaced) or
    N bot cars (head-to-bot, DeepRacer's default speed), :data:`DEFAULT_OBJECTS` when N is None; a time trial has
    none (ValueError for a count there)."""
    kind = RaceType(str(race_type).upper())
    if kind is RaceType.TIME_TRIAL:
        if objects:
            raise ValueError("a TIME_TRIAL race has no obstacles or bot cars")
        return RaceConfig()
    count = DEFAULT_OBJECTS[kind] if objects is None else objects
    if kind is RaceType.OBJECT_AVOIDANCE:
        return RaceConfig(race_type=kind, object_avoidance=ObjectAvoidanceConfig(number_of_obstacles=count))
    return RaceConfig(race_type=kind, head_to_bot=HeadToBotConfig(number_of_bot_cars=count))


def write_sensor_space(folder: str | Path, sensors: Sequence[str], base: str | None = None) -> Path:
    """A model_metadata.json in ``folder``: the action space of ``base`` (DeepRacer's default without one) with
    ``sensors`` as its ``sensor`` list; ValueError for a list racer does not build."""
    observation_spec(list(sensors))  # names the problem
    space = load_action_space(base) if base else default_action_space()
    path = Path(folder) / "model_metadata.json"
    path.write_text(space.model_copy(update={"sensor": list(sensors)}).to_json())
    return path


def pin_to_one_core() -> int | None:
    """Run this process on one CPU core with single-threaded OpenCV; returns the core, or None if unsupported."""
    cv2.setNumThreads(1)
    with contextlib.suppress(ImportError):
        import torch

        torch.set_num_threads(1)  # two OpenMP threads spinning on one core are many times slower than one
    if not hasattr(os, "sched_setaffinity"):
        return None
    core = sorted(os.sched_getaffinity(0))[-1]
    os.sched_setaffinity(0, {core})
    return core


def _timed_steps(env: RacerEnv, steps: int, rng: np.random.Generator) -> float:
    """Seconds for ``steps`` env.step calls with random actions (resets excluded from the clock)."""
    env.reset(seed=int(rng.integers(1 << 31)))
    total = 0.0
    for _ in range(steps):
        action = env.action_space.sample()
        t0 = time.perf_counter()
        _, _, term, trunc, _ = env.step(action)
        total += time.perf_counter() - t0
        if term or trunc:
            env.reset()
    return total


def _physics_us(env: RacerEnv, steps: int) -> float:
    """Microseconds per control step of the physics alone, driven by random actions as in training."""
    env.reset(seed=0)
    total = 0.0
    for i in range(steps):
        command = env.actions.command(env.action_space.sample())
        t0 = time.perf_counter()
        env.physics.command(*command)
        env.physics.step()
        total += time.perf_counter() - t0
        if i % 60 == 59:  # a fresh start now and then, as episodes end
            env.reset()
    return total / steps * 1e6


def env_parts_us(env: RacerEnv, steps: int, extended: bool = False) -> dict[str, float | None]:
    """Microseconds per step of each part, timed separately on the same code the env runs. ``extended`` adds
    ``lidar`` (the scan and its observation) and ``objects`` (the race's objects each step), None where the env
    has none; the camera is then the camera alone (without, it is the whole observation, as it always was)."""
    out: dict[str, float | None] = {"physics": _physics_us(env, steps)}
    env.reset(seed=0)
    ph, task = env.physics, env.task
    command = env.actions.command(env.action_space.sample())
    objects = env.objects
    result = task.observe(ph.pose, ph.wheel_positions(), True, ph.time, command, objects=objects)

    def task_step() -> None:
        task.observe(ph.pose, ph.wheel_positions(), ph.upright, ph.time, command, objects=objects)

    def reward() -> None:
        env.reward_fn(result.params, step=1)

    def camera() -> None:
        if extended:
            env.camera_frame(ph.pose)
        else:
            env.observe()

    parts: dict[str, Callable[[], None]] = {"camera": camera}
    if extended and env.lidar is not None:
        lidar, sensor = env.lidar, env.obs_spec.lidar.name

        def scan() -> None:
            lidar_from_ranges(sensor, lidar.scan(ph.pose, env.np_random))

        parts["lidar"] = scan
    elif extended:
        out["lidar"] = None
    if extended and env.race.slots:
        parts["objects"] = env.move_objects
    elif extended:
        out["objects"] = None
    parts.update(task=task_step, reward=reward)
    for name, fn in parts.items():
        t0 = time.perf_counter()
        for _ in range(steps):
            fn()
        out[name] = (time.perf_counter() - t0) / steps * 1e6
    order = ("physics", "camera", "lidar", "objects", "task", "reward")
    return {name: out[name] for name in order if name in out}


def bench_env(
    config: EnvConfig,
    steps: int = 2000,
    repeats: int = 5,
    seed: int = 0,
    sensors: Sequence[str] | None = None,
    race: RaceConfig | None = None,
) -> dict:
    """Measure env steps/s (physics + camera + task + reward) on one core; medians over ``repeats`` runs.

    ``sensors`` (a model_metadata ``sensor`` list, written into a temporary copy of the config's action space) and
    ``race`` (replacing the config's) extend the result: see the module doc."""
    core = pin_to_one_core()
    extended = sensors is not None or race is not None
    if race is not None:
        config = config.model_copy(update={"race": race})
    with tempfile.TemporaryDirectory(prefix="racer-bench-env-") as tmp:
        if sensors is not None:
            space = write_sensor_space(tmp, sensors, config.action_space)
            config = config.model_copy(update={"action_space": str(space)})
        env = RacerEnv(config=config)  # reads the file now
    env.action_space.seed(seed)
    rng = np.random.default_rng(seed)
    _timed_steps(env, 200, rng)  # warm caches and allocators
    rates = [steps / _timed_steps(env, steps, rng) for _ in range(repeats)]
    parts = [env_parts_us(env, max(200, steps // 4), extended) for _ in range(repeats)]
    env.close()
    result: dict = {
        "steps_per_s": statistics.median(rates),
        "steps_per_s_runs": [round(r, 1) for r in rates],
        "track": config.track,
        "camera": config.camera,
        "steps_per_run": steps,
        "repeats": repeats,
    }
    if extended:
        result.update(sensor=list(env.obs_spec.sensors), race_type=config.race.race_type.value, objects=env.race.slots)
    for name in parts[0]:
        values = [p[name] for p in parts]
        result[f"{name}_us_per_step"] = None if values[0] is None else statistics.median(values)
    result["machine"] = {"cpu": platform.processor() or platform.machine(), "core": core, "cores": os.cpu_count()}
    return result


_ENV_PARTS = ("physics", "camera", "task", "reward")
"""The parts reported for the plain env (no sensor list, no race)."""


def command(
    track: str,
    steps: int,
    repeats: int,
    *,
    camera: str,
    car_calibration: str | None,
    sensor: str | None,
    race_type: str | None,
    obstacles: int | None,
) -> Report:
    """``racer bench env``: check the options (``sensor`` a comma-separated model_metadata sensor list), time the
    env and report its rate and parts."""
    from common.car_calibration import CarCalibration, load_car
    from common.errors import OptionError
    from common.sensors import sensor_problem

    sensors = [s.strip() for s in sensor.split(",") if s.strip()] if sensor is not None else None
    if sensors is not None:
        problem = sensor_problem(sensors) if sensors else "no sensor given"
        if problem:
            raise OptionError(f"--sensor {sensor!r}: {problem}")
    race = None
    if race_type is not None:
        names = [t.value for t in RaceType]
        if race_type.upper() not in names:
            raise OptionError(f"--race-type {race_type!r} is not one of {', '.join(names)}")
        if obstacles and race_type.upper() == RaceType.TIME_TRIAL:
            raise OptionError("--obstacles needs --race-type OBJECT_AVOIDANCE or HEAD_TO_BOT")
        race = race_config(race_type, obstacles)
    elif obstacles is not None:
        raise OptionError("--obstacles needs --race-type OBJECT_AVOIDANCE or HEAD_TO_BOT")
    car = load_car(car_calibration) if car_calibration else CarCalibration()
    config = EnvConfig(track=track, camera=camera, car=car)
    result = bench_env(config, steps=steps, repeats=repeats, sensors=sensors, race=race)
    table = Table("figure", "value")
    table.add_row("env steps/s (median)", f"{result['steps_per_s']:.0f}")
    table.add_row("runs", ", ".join(f"{r:.0f}" for r in result["steps_per_s_runs"]))
    extended = "sensor" in result
    if extended:
        table.add_row("sensors", ", ".join(result["sensor"]))
        table.add_row("race", f"{result['race_type']}, {result['objects']} objects")
    parts = ("physics", "camera", "lidar", "objects", "task", "reward") if extended else _ENV_PARTS
    for part in parts:
        value = result[f"{part}_us_per_step"]
        table.add_row(f"{part} µs/step", "-" if value is None else f"{value:.1f}")
    return Report(result, [table])
