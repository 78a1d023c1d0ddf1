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
    video_trial: int | None = None,
) -> dict:
    """Evaluate and return the record (summary and trials); optionally write a sim-trace CSV and a video (of every
    trial, or of trial ``video_trial`` alone, 1-based). ``greedy_action`` (None: the run's) sets how a continuous
    policy acts (``Hyperparameters.greedy_action``); ``device`` where the network acts (``trainer.device``)."""
    on = resolve_device(device)
    trial_count = max(len(tracks), 1) * (2 if both_directions else 1) * episodes
    if video_trial is not None and video is None:
        raise OptionError(f"--video-trial {video_trial} needs --video FILE")
    if video_trial is not None and not 1 <= video_trial <= trial_count:
        raise OptionError(f"--video-trial {video_trial}: the evaluation has {trial_count} trials (1-{trial_count})")
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
            record["video"] = write_video(runs, run, env_cfg, record["version"], settings, video, video_trial, on)
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
    only: int | None = None,
    device: torch.device | str = "cpu",
) -> dict:
    """MP4 of the evaluation's trials, driven again as ``evaluate`` drove them (the same starts, seeds and noise):
    all of them one after another, or trial ``only`` alone (1-based, as ``racer eval``'s table numbers them). The
    top-down panel is one track's, so with several tracks each gets its own file, ``path``'s name + ``-<track>``.
    The network acts on ``device``. Returns the files, the frames and what each trial did in the video."""
    from common.policy import load_policy
    from common.sensors import camera_frame_size
    from sim.env import RacerEnv
    from sim.video import EpisodeVideo
    from trainer.evaluator import evaluation_env_config, trial_plan, trial_start

    plan = trial_plan(settings, env_cfg.track)
    chosen = range(len(plan)) if only is None else [only - 1]
    tracks = list(dict.fromkeys(plan[k][0] for k in chosen))
    model = None
    files, trials = [], []
    for track in tracks:
        env = RacerEnv(config=evaluation_env_config(env_cfg, settings, track))
        if model is None:
            frame = camera_frame_size(env.observation_space)
            model, _ = load_policy(runs, run, env.actions, version, frame=frame, device=device)
        out = path if len(tracks) == 1 else path.with_name(f"{path.stem}-{Path(track).stem}{path.suffix}")
        with EpisodeVideo(out, env.track, env.texture, env.frame) as video:
            for k in [k for k in chosen if plan[k][0] == track]:
                _, reverse, i = plan[k]
                start, seed = trial_start(env, settings, reverse, i)
                label = f"trial {k + 1}/{len(plan)} {'reverse' if reverse else 'forward'} from {start}"
                trial = _filmed_trial(video, env, model, run, settings, start, reverse, seed, label)
                trials.append(
                    {
                        "trial": k + 1,
                        "path": str(out),
                        "track": trial.track,
                        "reverse": reverse,
                        "start_index": start,
                        "status": trial.status,
                        "progress": trial.progress,
                        "steps": trial.steps,
                    }
                )
        env.close()
        files.append({"path": str(out), "frames": video.frames})
    return {
        "path": files[0]["path"],
        "frames": sum(f["frames"] for f in files),
        "files": files,
        "of": len(plan),
        "trials": trials,
    }


def _filmed_trial(video, env, model, run: RunConfig, settings: EvalSettings, start, reverse, seed, label: str):
    """Drive one trial (``trainer.evaluator.run_trial``) and add each of its frames to ``video``, labelled."""
    from common.sensors import split_observation
    from trainer.evaluator import run_trial

    def on_step(observation, info) -> None:
        p = info["params"]
        # The video shows what the policy sees: the camera (both images of a stereo pair) and the LiDAR.
        camera, lidar = split_observation(observation)
        video.add(
            camera,
            info["pose"],
            f"{label}  progress {p['progress']:.1f} %  {info['episode_status']}",
            env.objects,
            lidar,
        )

    stack = run.hyperparams.stack_size
    return run_trial(env, model, stack, start, reverse, seed, settings.deterministic, on_step, resets=settings.resets)


def video_lines(video: dict) -> list[str]:
    """What ``racer eval --video`` wrote, one line per file: where, which trials, how long."""
    lines = []
    for f in video["files"]:
        trials = [t for t in video["trials"] if t["path"] == f["path"]]
        length = f"{f['frames']} frames, {f['frames'] / 15:.0f} s at 15 fps"
        if len(trials) == 1:
            t = trials[0]
            what = (
                f"trial {t['trial']} of {video['of']} ({'reverse' if t['reverse'] else 'forward'} from start "
                f"{t['start_index']} on {t['track']}: {t['status']} at {t['progress']:.1f} %)"
            )
        elif len(trials) == video["of"]:
            what = f"all {len(trials)} trials, one after another"
        else:
            what = f"the {len(trials)} trials on {trials[0]['track']} ({trials[0]['trial']}-{trials[-1]['trial']})"
        lines.append(f"wrote {f['path']}: {what}, {length}")
    return lines


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
