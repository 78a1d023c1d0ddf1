"""``racer bench train``: time to a robust lap from scratch, racer against Stable-Baselines3 PPO on the same env.

Both systems train on the same ``RacerEnv`` (track, DeepRacer's default action space and reward function) with
the same hyperparameters as far as they map, and both are judged by the same robust evaluation
(``trainer.evaluator.evaluate``: starts spread around the lap, both directions, 10 % action noise, greedy
actions). A system has lapped at the first policy whose evaluation completes every lap.

Time to lap is wall-clock from the start (process start-up included) to the moment that policy existed:

* racer: the trainer's metrics row of that policy version (written right after its checkpoint). The evaluator
  runs beside the trainer as ``racer train`` runs it, on the same two cores, so its cost is inside racer's time.
* SB3: the end of the PPO update that made the policy, minus the time spent evaluating earlier policies
  (SB3's evaluation callback stops training while it runs, so its time is not SB3's training time).

Env steps to lap are the env steps the learner had consumed when it made that policy.
"""

from __future__ import annotations

import dataclasses
import io
import statistics
import tempfile
import time
from dataclasses import KW_ONLY, asdict, dataclass, field
from functools import partial
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from common.config import EnvConfig, RunConfig
from common.defaults import DEFAULT_TRACK
from common.tensorboard import tensorboard_without_tensorflow
from model_store import LocalStore, RunStore
from racer.bench import Report
from racer.embedded_redis import EmbeddedRedis
from racer.launcher import run_train
from racer.options import RunOptions
from racer.runconfig import build_run
from trainer.evaluator import EvalSettings, evaluate, summarize


@dataclass(kw_only=True)
class BenchTrainSettings:
    """What ``racer bench train`` runs."""

    seeds: list[int] = field(default_factory=lambda: [0, 1, 2])
    time_limit_s: float = 600.0
    """Give up on a seed after this long (per system)."""
    track: str = DEFAULT_TRACK
    hyperparams: str | None = None
    """A DeepRacer hyperparameters.json for both systems; None = racer's defaults."""
    workers: int = 2
    """racer's rollout workers, and SB3's SubprocVecEnv envs."""
    eval_episodes: int = 3
    """Evaluation starts per direction."""
    sb3: bool = True
    sb3_n_steps: int | None = None
    """SB3's rollout length per env between updates; None = racer's median batch per update on the same seed
    divided by ``workers``, so both update on as many env steps (racer's batch is 20 episodes, DeepRacer's
    ``num_episodes_between_training``, which has no SB3 equivalent)."""
    precision: str = "auto"
    """racer's PPO update arithmetic (``racer train --precision``)."""
    teacher: bool = False
    """Each seed also with ``racer train --teacher`` (system ``teacher``): the teacher until its first robust
    checkpoint (at most a third of ``time_limit_s``), then its student until the student's first; time to lap counts
    both stages."""


@dataclass
class LapRun:
    """One system's run on one seed."""

    system: str
    seed: int
    _: KW_ONLY
    lapped: bool
    time_to_lap_s: float | None
    env_steps_to_lap: int | None
    wall_s: float
    """Wall-clock of the whole run, evaluations included."""
    curve: list[dict]
    """Per evaluated policy: version, env_steps, time_s (as time_to_lap_s counts it), confirmed_s (when its
    evaluation had finished, on the same clock), completion_rate, mean_progress, best_lap_s."""
    batch_steps: int
    """Median env steps per policy update."""
    first_policy_s: float | None = None
    """When the first trained policy existed: start-up, one collection and one update."""
    update_s: float | None = None
    """Median seconds from one policy to the next: one collection and one update, the unit time to lap is
    made of (the number of updates a seed needs varies more than this)."""
    confirmed_s: float | None = None
    """When the evaluation that found the lap had finished (racer's evaluator runs beside training, at a lower
    CPU priority, so this is later than time_to_lap_s)."""


def _first_lap(curve: list[dict]) -> dict | None:
    return next((point for point in curve if point["completion_rate"] >= 1.0), None)


def _lap_run(
    system: str, seed: int, curve: list[dict], *, wall_s: float, batch_steps: int, made_s: list[float]
) -> LapRun:
    """The run's figures from its evaluation curve and the times (from the start) each policy was made."""
    first = _first_lap(curve)
    gaps = [b - a for a, b in zip(made_s, made_s[1:], strict=False)]
    return LapRun(
        system,
        seed,
        lapped=first is not None,
        time_to_lap_s=first["time_s"] if first else None,
        env_steps_to_lap=first["env_steps"] if first else None,
        wall_s=wall_s,
        curve=curve,
        batch_steps=batch_steps,
        first_policy_s=made_s[0] if made_s else None,
        update_s=statistics.median(gaps) if gaps else None,
        confirmed_s=first["confirmed_s"] if first else None,
    )


# --- racer ------------------------------------------------------------------------------------------------
def racer_curve(run_id: str, runs: RunStore, t0: float) -> list[dict]:
    """The evaluated policies of a finished ``racer train`` run, in version order, with the time each policy was
    made (its metrics row) relative to ``t0`` (a ``time.time()``)."""
    made = {
        int(row["policy_version"]): (float(row["time"]), int(row["env_steps"]))
        for row in runs.read_metrics(run_id, missing_ok=True)
    }
    curve = []
    for record in runs.read_evaluations(run_id):
        version = int(record["version"])
        if version not in made:  # version 0 (the untrained policy) has no metrics row
            continue
        made_at, env_steps = made[version]
        curve.append(_point(version, env_steps, made_at - t0, record, float(record["created"]) - t0))
    return curve


def _point(version: int, env_steps: int, time_s: float, summary: dict, confirmed_s: float) -> dict:
    return {
        "version": version,
        "env_steps": env_steps,
        "time_s": round(time_s, 2),
        "confirmed_s": round(confirmed_s, 2),
        "completion_rate": summary["completion_rate"],
        "mean_progress": round(summary["mean_progress"], 2),
        "best_lap_s": summary["best_lap_s"],
    }


def run_racer(settings: BenchTrainSettings, seed: int, *, teacher: bool = False) -> LapRun:
    """``racer train`` from scratch until an evaluated checkpoint completes every evaluation lap; with ``teacher``,
    ``racer train --teacher`` (``BenchTrainSettings.teacher``), timed from the teacher's start."""
    with EmbeddedRedis() as server, tempfile.TemporaryDirectory(prefix="racer-bench-train-") as store:
        run_id = f"bench-train-s{seed}"
        run, files = build_run(run_id, track=settings.track, hyperparams=settings.hyperparams, seed=seed)
        opts = RunOptions(
            run_id=run_id,
            workers=settings.workers,
            redis_url=server.url,
            store=store,
            time_limit_s=settings.time_limit_s,
            eval_every=1,
            eval_episodes=settings.eval_episodes,
            stop_when_robust=1,
            precision=settings.precision,
        )
        runs = RunStore(LocalStore(store))
        t0 = time.time()
        if teacher:
            from racer.teacher import split_time, train_with_teacher

            quiet = Console(file=io.StringIO())
            teacher_s = split_time(opts, None)
            train_with_teacher(runs, opts, (run, files), distill={}, teacher_time_s=teacher_s, console=quiet)
        else:
            run_train(run, opts, files, Console(file=io.StringIO()))
        wall = time.time() - t0
        curve = racer_curve(run_id, runs, t0)
        rows = runs.read_metrics(run_id, missing_ok=True)
    batch = int(statistics.median(int(row["batch_steps"]) for row in rows)) if rows else 0
    return _lap_run(
        "teacher" if teacher else "racer",
        seed,
        curve,
        wall_s=wall,
        batch_steps=batch,
        made_s=[float(row["time"]) - t0 for row in rows],
    )


# --- Stable-Baselines3 ------------------------------------------------------------------------------------
class SB3Actor:
    """An SB3 policy with the two methods ``trainer.evaluator.run_trial`` uses, so both systems are evaluated
    by the very same code."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy

    def eval(self) -> SB3Actor:
        """Inference mode (no dropout or batch-norm updates; SB3's CnnPolicy has neither)."""
        self.policy.set_training_mode(False)
        return self

    def act_numpy(
        self, obs: np.ndarray, deterministic: bool = False, lidar: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Actions for a uint8 (B, H, W, C) batch; log-probs and values are not needed by the evaluation. The
        benchmark drives the front camera only: ``lidar`` is always None (``run_trial`` passes it)."""
        if lidar is not None:
            raise ValueError("the SB3 benchmark policy has no LiDAR input")
        actions, _ = self.policy.predict(obs, deterministic=deterministic)  # transposes channels-last itself
        zeros = np.zeros(len(actions), np.float32)
        return np.asarray(actions), zeros, zeros


def sb3_ppo_kwargs(run: RunConfig, n_steps: int, seed: int) -> dict:
    """SB3 PPO arguments for the run's hyperparameters. SB3 has no Huber value loss (it uses MSE), and it
    collects a fixed ``n_steps`` per env between updates where DeepRacer collects a number of episodes."""
    hp = run.hyperparams
    return {
        "learning_rate": hp.lr,
        "n_steps": n_steps,
        "batch_size": hp.batch_size,
        "n_epochs": hp.num_epochs,
        "gamma": hp.discount_factor,
        "gae_lambda": hp.gae_lambda,
        "clip_range": hp.clip_epsilon,
        "ent_coef": hp.beta_entropy,
        "vf_coef": hp.value_loss_coef,
        "max_grad_norm": hp.max_grad_norm,
        "seed": seed,
        "device": "cpu",
        "verbose": 0,
    }


def run_sb3(settings: BenchTrainSettings, seed: int, n_steps: int) -> LapRun:
    """SB3 PPO (CnnPolicy: NatureCNN, the same layers as DeepRacer's shallow network) on a SubprocVecEnv of
    ``workers`` envs, ``n_steps`` per env and update, evaluated after every update until a policy completes
    every evaluation lap."""
    tensorboard_without_tensorflow()  # SB3's logger imports TensorBoard
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import SubprocVecEnv

    run, _ = build_run(f"bench-train-sb3-s{seed}", track=settings.track, hyperparams=settings.hyperparams, seed=seed)
    eval_settings = EvalSettings(episodes=settings.eval_episodes)
    curve: list[dict] = []
    t0 = time.time()
    eval_s = 0.0

    class RobustEval(BaseCallback):
        """After every PPO update: the robust evaluation; stop at the first full completion or the time limit."""

        def __init__(self) -> None:
            super().__init__()
            self.done = False

        def _on_rollout_start(self) -> None:
            nonlocal eval_s
            if self.model.num_timesteps == 0:  # before the first rollout: nothing trained yet
                return
            made_at = time.time() - t0 - eval_s
            start = time.time()
            summary = summarize(evaluate(SB3Actor(self.model.policy), run.env, 1, eval_settings))
            took = time.time() - start
            eval_s += took
            curve.append(_point(len(curve) + 1, int(self.model.num_timesteps), made_at, summary, made_at + took))
            self.done = summary["completion_rate"] >= 1.0 or made_at > settings.time_limit_s

        def _on_step(self) -> bool:
            return not self.done

    env_fns = [partial(_sb3_env, run.env) for _ in range(settings.workers)]
    venv = SubprocVecEnv(env_fns)
    try:
        model = PPO("CnnPolicy", venv, **sb3_ppo_kwargs(run, n_steps, seed))
        model.learn(total_timesteps=10**9, callback=RobustEval())
    finally:
        venv.close()
    made = [point["time_s"] for point in curve]
    return _lap_run("sb3", seed, curve, wall_s=time.time() - t0, batch_steps=n_steps * settings.workers, made_s=made)


def _sb3_env(env_cfg: EnvConfig) -> Any:
    """One env for SB3's SubprocVecEnv (a module-level function: the child process imports it)."""
    from sim.env import RacerEnv

    return RacerEnv(config=env_cfg)


# --- the bench ---------------------------------------------------------------------------------------------
def _spread(values: list[float]) -> dict:
    return {"min": min(values), "median": statistics.median(values), "max": max(values)} if values else {}


def summarize_bench(runs: list[LapRun], settings: BenchTrainSettings) -> dict:
    """The JSON of ``racer bench train``: medians over seeds, the spread, every run's curve.

    A median is over the seeds that lapped; ``lapped`` says how many did. A seed that did not lap within the
    time limit counts as the limit in ``*_bound_s`` (a lower bound), so a system that failed is not flattered.
    """
    out: dict[str, Any] = {"seeds": settings.seeds, "settings": asdict(settings)}
    for system, prefix in (("racer", ""), ("sb3", "sb3_"), ("teacher", "")):
        mine = [r for r in runs if r.system == system]
        if not mine:
            continue
        if system == "teacher":  # racer train --teacher: a block of its own, the plain run's keys
            out["teacher"] = summarize_bench(
                [dataclasses.replace(r, system="racer") for r in mine], dataclasses.replace(settings, teacher=False)
            )
            del out["teacher"]["runs"], out["teacher"]["settings"], out["teacher"]["seeds"]
            if out.get("time_to_lap_bound_s"):
                out["teacher"]["speedup"] = out["time_to_lap_bound_s"] / out["teacher"]["time_to_lap_bound_s"]
            continue
        lapped = [r for r in mine if r.lapped]
        times = [r.time_to_lap_s for r in lapped]
        steps = [r.env_steps_to_lap for r in lapped]
        bounded = [r.time_to_lap_s if r.lapped else settings.time_limit_s for r in mine]
        out[f"{prefix}time_to_lap_s"] = statistics.median(times) if times else None
        out[f"{prefix}env_steps_to_lap"] = statistics.median(steps) if steps else None
        out[f"{prefix}time_to_lap_bound_s"] = statistics.median(bounded)
        out[f"{prefix}time_to_lap_spread_s"] = _spread(times)
        out[f"{prefix}confirmed_s"] = statistics.median([r.confirmed_s for r in lapped]) if lapped else None
        for key in ("first_policy_s", "update_s"):
            values = [getattr(r, key) for r in mine if getattr(r, key) is not None]
            out[f"{prefix}{key}"] = statistics.median(values) if values else None
        out[f"{prefix}env_steps_to_lap_spread"] = _spread(steps)
        out[f"{prefix}lapped"] = f"{len(lapped)}/{len(mine)}"
    if "sb3_time_to_lap_bound_s" in out and out.get("time_to_lap_bound_s"):
        out["speedup_vs_sb3"] = out["sb3_time_to_lap_bound_s"] / out["time_to_lap_bound_s"]
    out["runs"] = [asdict(r) for r in runs]
    return out


def bench_train(settings: BenchTrainSettings, progress: Console | None = None) -> dict:
    """Every seed with racer, then (unless disabled) with SB3, one at a time so they never share the cores."""
    runs = []
    for seed in settings.seeds:
        runs.append(run_racer(settings, seed))
        _report(runs[-1], settings, progress)
        if settings.teacher:
            runs.append(run_racer(settings, seed, teacher=True))
            _report(runs[-1], settings, progress)
        if settings.sb3:
            n_steps = settings.sb3_n_steps or max(8, round(runs[-1].batch_steps / settings.workers))
            runs.append(run_sb3(settings, seed, n_steps))
            _report(runs[-1], settings, progress)
    return summarize_bench(runs, settings)


def _report(result: LapRun, settings: BenchTrainSettings, progress: Console | None) -> None:
    if progress is None:
        return
    what = (
        f"lapped in {result.time_to_lap_s:.0f} s, {result.env_steps_to_lap} env steps"
        if result.lapped
        else f"no robust lap within {settings.time_limit_s:.0f} s"
    )
    progress.print(
        f"seed {result.seed} {result.system}: {what} ({result.batch_steps} steps per update; run {result.wall_s:.0f} s)"
    )


def command(settings: BenchTrainSettings, progress: Console | None = None) -> Report:
    """``racer bench train``: check the run's files and the SB3 install, train, and compare racer with SB3 PPO."""
    from common.config import check_precision
    from common.errors import OptionError

    check_precision(settings.precision)
    build_run("bench-check", track=settings.track, hyperparams=settings.hyperparams)  # bad files fail here, in one line
    if settings.sb3:
        try:
            tensorboard_without_tensorflow()  # SB3 imports TensorBoard
            import stable_baselines3  # noqa: F401
        except ImportError:
            raise OptionError("--sb3 needs Stable-Baselines3: pip install 'racer[bench]' (or pass --no-sb3)") from None
    result = bench_train(settings, progress)
    table = Table("figure", "racer", "SB3 PPO")
    for label, key in (("time to lap s (median)", "time_to_lap_s"), ("env steps to lap", "env_steps_to_lap")):
        table.add_row(label, _whole(result.get(key)), _whole(result.get(f"sb3_{key}")))
    table.add_row("seeds lapped", str(result.get("lapped")), str(result.get("sb3_lapped", "-")))
    shown: list[Table | str] = [table]
    if "speedup_vs_sb3" in result:
        shown.append(f"racer reaches a robust lap {result['speedup_vs_sb3']:.2f}× as fast as SB3 PPO")
    if "teacher" in result:
        taught = result["teacher"]
        shown.append(
            f"with a teacher (racer train --teacher): time to lap {_whole(taught['time_to_lap_s'])} s, "
            f"{_whole(taught['env_steps_to_lap'])} env steps, {taught['lapped']} seeds lapped"
            + (f"; {taught['speedup']:.2f}× as fast as the plain run" if "speedup" in taught else "")
        )
    return Report(result, shown)


def _whole(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"
