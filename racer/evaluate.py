"""``racer eval``: evaluate any checkpoint of any run from a store, on any track."""

from __future__ import annotations

import json
import logging
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, get_args

from common.action_space import ActionSpace
from common.car_calibration import load_car
from common.conditions import Condition, load_conditions
from common.config import EnvConfig, RunConfig
from common.errors import OptionError
from common.hyperparams import GreedyAction
from common.simtrace import SimTraceRecorder
from model_store import RunStore, StoreError, open_store
from model_store.localize import localize_env
from trainer.device import resolve_device
from trainer.evaluator import EvalSettings, evaluate_checkpoint, evaluate_conditions

if TYPE_CHECKING:
    import torch

log = logging.getLogger("racer.eval")

Progress = Callable[[str], None]
"""Where ``run_eval`` says how far it got, one short line at a time (``racer eval`` prints them on stderr)."""


def _ignore(line: str) -> None:
    """Progress nobody reads."""


def run_eval(
    run_id: str,
    store: str,
    s3_endpoint: str | None,
    *,
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
    conditions: list[str] | None = None,
    on_progress: Progress | None = None,
) -> dict:
    """Evaluate and return the record (summary and trials); optionally write a sim-trace CSV and a video (of every
    trial, or of trial ``video_trial`` alone, 1-based). ``greedy_action`` (None: the run's) sets how a continuous
    policy acts (``Hyperparameters.greedy_action``); ``device`` where the network acts (``trainer.device``).

    ``conditions`` (``--condition`` values, ``common.conditions``): after the run's own world, the same trials
    in each held-out condition; the record's ``conditions`` gives each one's laps out of the trials, progress and
    lap times (the sim-trace and the video are of the run's own world).

    ``on_progress`` gets a line as each part ends (which checkpoint, each pass of the trials, each condition, each
    filmed trial): an evaluation takes minutes. With a video, its first file is also stored where ``racer view``
    plays checkpoint videos (``store_video``), and the record's ``video.view`` says where (None: it could not be).
    """
    held_out = load_conditions(conditions or [])  # a bad name is said before anything is driven
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
    say = on_progress or _ignore
    # Resolved once: the version said is the one driven, even while an evaluator moves ``best``.
    version = runs.resolve(run_id, checkpoint)
    steps = runs.checkpoint_meta(run_id, version).get("env_steps")
    said = "" if str(checkpoint) == str(version) else f"{checkpoint}, "
    say(f"checkpoint v{version} of run {run_id} ({said}{steps if steps is not None else '?'} env steps), on {on}")
    settings = EvalSettings(
        episodes=episodes, both_directions=both_directions, action_noise=action_noise, tracks=tracks, resets=resets
    )
    with tempfile.TemporaryDirectory(prefix="racer-eval-") as tmp:
        env_cfg = localize_env(run, runs, Path(tmp))
        recorder = SimTraceRecorder() if sim_trace is not None else None
        say(_plan_line(settings, env_cfg.track, trial_count))
        started = time.monotonic()
        record = evaluate_checkpoint(runs, run, env_cfg, version, settings, recorder=recorder, device=on)
        say(_pass_line("as trained", record, len(record["lap_times_s"]), time.monotonic() - started))
        if held_out:
            driven = _drive_conditions(runs, run, env_cfg, version, settings, conditions=held_out, device=on, say=say)
            record["conditions"] = driven
        if recorder is not None:
            Path(sim_trace).write_text(recorder.take(include_open=True) or "")
        if video is not None:
            filmed = write_video(
                runs, run, env_cfg, version, settings, path=video, only=video_trial, device=on, on_progress=say
            )
            filmed["view"] = store_video(runs, run_id, version, Path(filmed["path"]))
            record["video"] = filmed
        return record


def _plan_line(settings: EvalSettings, run_track: str, trials: int) -> str:
    """What the evaluation is about to drive: its trials, tracks and directions."""
    tracks = ", ".join(_track_label(t) for t in settings.tracks or [run_track])
    directions = "both directions" if settings.both_directions else "forward only"
    starts = _count(settings.episodes, "start")
    return f"driving {_count(trials, 'trial')} on {tracks} ({starts} per direction, {directions}), side by side"


def _count(n: int, thing: str) -> str:
    """``1 lap``, ``2 laps``."""
    return f"{n} {thing}{'' if n == 1 else 's'}"


def _track_label(spec: str) -> str:
    """A track as a line names it: a .npy path by its stem (racer's own tracks are names already)."""
    return Path(spec).stem if spec.endswith(".npy") else spec


def _pass_line(name: str, figures: dict, laps: int, seconds: float) -> str:
    """One pass of the trials (the run's own world, or a held-out condition) once driven: laps, off-tracks and
    crashes out of the trials, mean progress, best lap."""
    best = "" if figures["best_lap_s"] is None else f" (best {figures['best_lap_s']:.2f} s)"
    driven = f"{_count(figures['episodes'], 'trial')} in {seconds:.0f} s"
    ends = f"{figures['off_track']} off track, {figures['crashed']} crashed"
    return f"{name}: {driven}: {_count(laps, 'lap')}{best}, {ends}, mean progress {figures['mean_progress']:.1f} %"


def _drive_conditions(
    runs: RunStore,
    run: RunConfig,
    env_cfg: EnvConfig,
    version: int,
    settings: EvalSettings,
    *,
    conditions: list[Condition],
    device: torch.device | str,
    say: Progress,
) -> list[dict]:
    """``evaluate_conditions``, one condition at a time so that each is said when it is driven."""
    rows: list[dict] = []
    for number, condition in enumerate(conditions, 1):
        started = time.monotonic()
        rows += evaluate_conditions(runs, run, env_cfg, version, settings, conditions=[condition], device=device)
        name = f"condition {number}/{len(conditions)} {condition.name}"
        say(_pass_line(name, rows[-1], rows[-1]["laps"], time.monotonic() - started))
    return rows


def store_video(runs: RunStore, run_id: str, version: int, path: Path) -> str | None:
    """Copy the MP4 at ``path`` to the run's ``videos/{version:09d}.mp4``, where ``racer view`` plays checkpoint
    ``version``'s video; its URI, or None (and a warning) when the store refuses it: the local file is the result
    asked for, and it is there."""
    from model_store.runs import run_prefix
    from racer.view.data import video_name

    try:
        runs.write_file(run_id, video_name(version), path.read_bytes())
    except StoreError as exc:
        log.warning("racer view will not show %s: %s", path, exc)
        return None
    return runs.store.key_uri(f"{run_prefix(run_id)}{video_name(version)}")


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
    *,
    path: Path,
    only: int | None = None,
    device: torch.device | str = "cpu",
    on_progress: Progress | None = None,
) -> dict:
    """MP4 of the evaluation's trials, driven again as ``evaluate`` drove them (the same starts, seeds and noise):
    all of them one after another, or trial ``only`` alone (1-based, as ``racer eval``'s table numbers them). The
    top-down panel is one track's, so with several tracks each gets its own file, ``path``'s name + ``-<track>``.
    The network acts on ``device``; ``on_progress`` gets a line per trial filmed. Returns the version, the files,
    the frames and what each trial did in the video."""
    from common.config import FRAME_HEIGHT, FRAME_WIDTH
    from common.sensors import camera_frame_size
    from common.weights import load_policy
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
            frame = (
                (FRAME_HEIGHT, FRAME_WIDTH)
                if env_cfg.observation == "state"
                else camera_frame_size(env.observation_space)
            )
            model, _ = load_policy(runs, run, env.actions, version, frame=frame, device=device)
        out = path if len(tracks) == 1 else path.with_name(f"{path.stem}-{Path(track).stem}{path.suffix}")
        with EpisodeVideo(out, env.track, env.texture, env.frame) as video:
            for k in [k for k in chosen if plan[k][0] == track]:
                _, reverse, i = plan[k]
                start, seed = trial_start(env, settings, reverse, i)
                label = f"trial {k + 1}/{len(plan)} {'reverse' if reverse else 'forward'} from {start}"
                trial = _filmed_trial(
                    video, env, model, run, settings, start=start, reverse=reverse, seed=seed, label=label
                )
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
                        "lap_time_s": trial.lap_time_s,
                    }
                )
                (on_progress or _ignore)(f"filmed {label}: {_outcome(trials[-1])}")
        env.close()
        files.append({"path": str(out), "frames": video.frames})
    return {
        "version": version,
        "path": files[0]["path"],
        "frames": sum(f["frames"] for f in files),
        "files": files,
        "of": len(plan),
        "trials": trials,
    }


def _filmed_trial(video, env, model, run: RunConfig, settings: EvalSettings, *, start, reverse, seed, label: str):
    """Drive one trial (``trainer.evaluator.run_trial``) and add each of its frames to ``video``, labelled."""
    from common.sensors import split_observation
    from trainer.evaluator import run_trial

    def on_step(observation, info) -> None:
        p = info["params"]
        # The video shows what the policy sees: the camera (both images of a stereo pair) and the LiDAR; a teacher
        # sees the car's state, and its video shows what the camera would have seen.
        camera, lidar = split_observation(observation)
        if camera.ndim != 3:
            camera = env.camera_frame(info["pose"])
        video.add(
            camera,
            info["pose"],
            f"{label}  progress {p['progress']:.1f} %  {info['episode_status']}",
            env.objects,
            lidar,
        )

    stack = run.hyperparams.stack_size
    return run_trial(
        env,
        model,
        stack,
        start,
        reverse,
        seed=seed,
        deterministic=settings.deterministic,
        on_step=on_step,
        resets=settings.resets,
    )


def _outcome(trial: dict) -> str:
    """How a trial ended, in a few words: its lap time, or its status and how far it got."""
    if trial.get("lap_time_s") is not None:
        return f"lap {trial['lap_time_s']:.2f} s"
    return f"{trial['status'].replace('_', ' ')} at {trial['progress']:.1f} %"


def video_lines(video: dict) -> list[str]:
    """What ``racer eval --video`` wrote, one line per file: where, which trials, how long; and where ``racer view``
    finds it (``video["view"]``, set by ``run_eval``)."""
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
    if video.get("view"):
        # racer view plays one video per checkpoint: with a file per track, the first track's.
        lines.append(f"stored {video['path']} as {video['view']}: racer view plays it as v{video['version']}'s video")
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
