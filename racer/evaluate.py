"""``racer eval``: evaluate any checkpoint of any run from a store, on any track."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, get_args

from common.action_space import ActionSpace
from common.car_calibration import load_car
from common.config import RunConfig
from common.errors import OptionError
from common.hyperparams import GreedyAction
from common.simtrace import SimTraceRecorder
from model_store import RunStore, open_store
from model_store.localize import localize_env
from trainer.device import resolve_device
from trainer.evaluator import EvalSettings, evaluate_checkpoint

if TYPE_CHECKING:
    import torch


def run_eval(
    run_id: str,
    store: str,
    s3_endpoint: str | None,
    checkpoint: str,
    tracks: list[str],
    episodes: int,
    both_directions: bool,
    action_noise: float,
    sim_trace: Path | None = None,
    video: Path | None = None,
    car_calibration: str | Path | None = None,
    resets: bool = True,
    greedy_action: str | None = None,
    device: str = "auto",
) -> dict:
    """Evaluate and return the record (summary and trials); optionally write a sim-trace CSV and a video.
    ``greedy_action`` (None: the run's) sets how a continuous policy acts (``Hyperparameters.greedy_action``);
    ``device`` where the network acts (``trainer.device``)."""
    on = resolve_device(device)
    runs = RunStore(open_store(store, s3_endpoint))
    run = runs.read_config(run_id)
    if car_calibration is not None:  # drive the policy on another car than the one it was trained on
        run = run.model_copy(update={"env": run.env.model_copy(update={"car": load_car(car_calibration)})})
    if greedy_action is not None:
        run = _with_greedy_action(runs, run, greedy_action)
    version: int | str = int(checkpoint) if checkpoint.isdigit() else checkpoint
    settings = EvalSettings(
        episodes=episodes, both_directions=both_directions, action_noise=action_noise, tracks=tracks, resets=resets
    )
    with tempfile.TemporaryDirectory(prefix="racer-eval-") as tmp:
        env_cfg = localize_env(run, runs, Path(tmp))
        recorder = SimTraceRecorder() if sim_trace is not None else None
        record = evaluate_checkpoint(runs, run, env_cfg, version, settings, recorder, on)
        if recorder is not None:
            Path(sim_trace).write_text(recorder.take(include_open=True) or "")
        if video is not None:
            record["video"] = write_video(runs, run, env_cfg, record["version"], settings, video, on)
        return record


def _with_greedy_action(runs: RunStore, run: RunConfig, greedy_action: str) -> RunConfig:
    """``run`` acting greedily by ``greedy_action``; OptionError for another value than ``GreedyAction``'s, or for
    ``expected`` on a discrete action space."""
    if greedy_action not in get_args(GreedyAction):
        raise OptionError(f"--greedy-action {greedy_action!r} is not one of {', '.join(get_args(GreedyAction))}")
    actions = ActionSpace.model_validate_json(runs.read_file(run.run_id, "model_metadata.json"))
    if greedy_action != "mean" and actions.discrete:
        raise OptionError(
            f"--greedy-action {greedy_action}: run {run.run_id!r} has a discrete action space, which acts by its argmax"
        )
    return run.model_copy(update={"policy": run.policy.model_copy(update={"greedy_action": greedy_action})})


def write_video(
    runs: RunStore,
    run: RunConfig,
    env_cfg,
    version: int,
    settings: EvalSettings,
    path: Path,
    device: torch.device | str = "cpu",
) -> dict:
    """MP4 of the first evaluation trial (forward, from waypoint 0): the camera beside the car on the track; the
    network acts on ``device``."""
    from common.policy import load_policy
    from common.sensors import camera_frame_size, split_observation
    from sim.env import RacerEnv
    from sim.video import EpisodeVideo
    from trainer.evaluator import run_trial

    track = (settings.tracks or [env_cfg.track])[0]
    noise = env_cfg.randomization.model_copy(update={"action_noise": settings.action_noise, "random_start": False})
    env = RacerEnv(config=env_cfg.model_copy(update={"track": track, "randomization": noise}))
    frame = camera_frame_size(env.observation_space)
    model, _ = load_policy(runs, run, env.actions, version, frame=frame, device=device)
    with EpisodeVideo(path, env.track, env.texture, env.frame) as video:

        def on_step(observation, info) -> None:
            p = info["params"]
            # The video shows what the policy sees: the camera (both images of a stereo pair) and the LiDAR.
            camera, lidar = split_observation(observation)
            text = f"progress {p['progress']:.1f} %  {info['episode_status']}"
            video.add(camera, info["pose"], text, env.objects, lidar)

        trial = run_trial(
            env,
            model,
            run.hyperparams.stack_size,
            0,
            False,
            settings.seed,
            settings.deterministic,
            on_step,
            resets=settings.resets,
        )
    env.close()
    return {"path": str(path), "frames": trial.steps + 1, "status": trial.status, "progress": trial.progress}


def models_table(store: str, s3_endpoint: str | None, run_id: str | None) -> list[dict]:
    """``racer models ls``: each checkpoint's metadata (without the bulky run config) and its evaluation figures."""
    from model_store import StoreKeyError, list_models
    from model_store.runs import evaluation_name

    obj_store = open_store(store, s3_endpoint)
    runs = RunStore(obj_store)
    rows = []
    for meta in list_models(obj_store, run_id):
        row = {k: v for k, v in meta.items() if k != "config"}
        try:
            ev = json.loads(runs.read_file(row["run_id"], evaluation_name(int(row["version"]))))
            row["evaluation"] = {k: ev.get(k) for k in ("completion_rate", "mean_progress", "best_lap_s", "score")}
        except (StoreKeyError, ValueError):
            row["evaluation"] = None
        rows.append(row)
    return rows
