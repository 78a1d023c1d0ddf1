"""``racer train`` (the whole loop on one machine) and ``racer check`` (the user's files, checked as train would)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from common.config import PRECISION_HELP, DistillConfig
from common.deadline import parse_duration
from common.defaults import DEFAULT_EVAL_EPISODES, DEFAULT_TRACK, DEFAULT_WORKERS
from common.errors import OptionError, UserError
from racer.commands.options import (
    ActionSpace,
    Car,
    Endpoint,
    EnvsPerWorker,
    FromDrfc,
    Hyperparams,
    RaceFile,
    RaceTypeOpt,
    RewardFn,
    Store,
    WorkerConfig,
    console,
    device_option,
)

# The defaults of --track and --workers are None in code (a --from-drfc folder may set them) and shown as what they
# come to; rich reads a "[default: …]" written into a help text as markup and prints none of it.
TrackOpt = Annotated[
    str | None,
    typer.Option(
        help="Track name or .npy path (not given: a --from-drfc folder's DR_WORLD_NAME, if any).",
        show_default=DEFAULT_TRACK,
    ),
]


def train(
    track: TrackOpt = None,
    workers: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Rollout worker processes (not given: a --from-drfc folder's DR_WORKERS, if any).",
            show_default=str(DEFAULT_WORKERS),
        ),
    ] = None,
    envs_per_worker: EnvsPerWorker = 1,
    time_limit: Annotated[
        str | None,
        typer.Option(
            "--time-limit", help="Stop after this long (90s, 5m, 2h).", show_default="none: train until Ctrl-C"
        ),
    ] = None,
    run_id: Annotated[str | None, typer.Option("--run-id", help="Run id (default: run-<UTC time>).")] = None,
    store: Store = ".",
    s3_endpoint: Endpoint = None,
    redis_url: Annotated[str | None, typer.Option("--redis", help="Use this Redis instead of an embedded one.")] = None,
    reward_fn: RewardFn = None,
    action_space: ActionSpace = None,
    hyperparams: Hyperparams = None,
    randomization: Annotated[Path | None, typer.Option(help="JSON of domain randomization settings.")] = None,
    worker_track: Annotated[
        list[str] | None, typer.Option("--worker-track", help="Per-worker tracks: worker k drives the k-th (cycling).")
    ] = None,
    worker_config: WorkerConfig = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue the run from its latest checkpoint.")] = False,
    seed: Annotated[int, typer.Option(help="Base random seed.")] = 0,
    car_calibration: Car = None,
    max_policy_lag: Annotated[int, typer.Option(min=0, help="Drop segments this many versions old.")] = 0,
    segment_steps: Annotated[int, typer.Option(min=1, help="Env steps per segment sent to Redis.")] = 32,
    evaluate: Annotated[bool, typer.Option("--eval/--no-eval", help="Run the evaluator beside the trainer.")] = True,
    eval_every: Annotated[int, typer.Option(min=1, help="Evaluate every N-th checkpoint.")] = 1,
    eval_episodes: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Evaluation starts per direction (not given: a --from-drfc folder's DR_EVAL_NUMBER_OF_TRIALS).",
            show_default=str(DEFAULT_EVAL_EPISODES),
        ),
    ] = None,
    eval_track: Annotated[list[str] | None, typer.Option("--eval-track", help="Evaluate on these tracks.")] = None,
    stop_when_robust: Annotated[
        int | None, typer.Option(min=1, help="Stop after K consecutive checkpoints complete every evaluation lap.")
    ] = None,
    precision: Annotated[str, typer.Option(help=PRECISION_HELP)] = "auto",
    device: Annotated[str, device_option()] = "auto",
    from_drfc: FromDrfc = None,
    race_type: RaceTypeOpt = None,
    race: RaceFile = None,
    pretrained: Annotated[
        str | None,
        typer.Option(help="Start from another run's weights in the store: RUN[:best|latest|N] (DRfC pretrained)."),
    ] = None,
    teacher: Annotated[
        bool,
        typer.Option(
            "--teacher",
            help="Train a privileged teacher on the car's state first (run RUN_ID-teacher), then the camera network "
            "learns to act as it does, then PPO (docs/teacher.md).",
        ),
    ] = False,
    teacher_time: Annotated[
        str | None,
        typer.Option(
            help="--teacher: the teacher's share of the time (90s, 5m).", show_default="a third of --time-limit"
        ),
    ] = None,
    distill_updates: Annotated[
        int, typer.Option(min=1, help="--teacher: the student's distillation updates before PPO.")
    ] = DistillConfig.model_fields["updates"].default,
    fine_tune: Annotated[
        bool, typer.Option("--fine-tune/--no-fine-tune", help="--teacher: PPO on the reward after distilling.")
    ] = True,
    view: Annotated[bool, typer.Option("--view", help="Serve racer view's page of the run (docs/view.md).")] = False,
    view_host: Annotated[str, typer.Option(help="--view's address; beyond loopback it needs a token.")] = "127.0.0.1",
    view_port: Annotated[int, typer.Option(min=0, max=65535, help="--view's port; 0 = a free one.")] = 8090,
) -> None:
    """Train: an embedded Redis (unless --redis), the PPO trainer and N rollout workers on this machine."""
    from model_store import RunStore, open_store
    from racer.check import drfc_lines, merge_inputs
    from racer.launcher import check_device_options, done_line, new_run_id, run_summary, run_train
    from racer.options import RunOptions
    from racer.runconfig import load_race, open_run, worker_settings

    check_device_options(device, precision)
    if resume and not run_id:
        raise OptionError("--resume needs --run-id")
    flags = RunOptions.from_flags(
        run_id=run_id,
        store=store,
        s3_endpoint=s3_endpoint,
        redis_url=redis_url,
        resume=resume,
        track=track,
        reward_fn=reward_fn,
        action_space=action_space,
        hyperparams=hyperparams,
        randomization=randomization,
        seed=seed,
        car_calibration=car_calibration,
        max_policy_lag=max_policy_lag,
        segment_steps=segment_steps,
        pretrained=pretrained,
        race=load_race(race, race_type),
        workers=workers,
        envs_per_worker=envs_per_worker,
        time_limit_s=time_limit,
        precision=precision,
        device=device,
        evaluate=evaluate,
        eval_every=eval_every,
        eval_episodes=eval_episodes,
        eval_tracks=eval_track or [],
        stop_when_robust=stop_when_robust,
        view=(view_host, view_port) if view else None,
    )
    merged, drfc = merge_inputs(flags, from_drfc)
    opts = merged.with_defaults()
    opts = opts.model_copy(
        update={
            "run_id": opts.run_id or new_run_id(),
            "worker_settings": worker_settings(worker_track, worker_config, opts.workers, drfc),
        }
    )
    if teacher and (resume or pretrained):
        raise OptionError(f"--teacher starts a new run: {'--resume' if resume else '--pretrained'} cannot go with it")
    runs = RunStore(open_store(store, s3_endpoint))
    run, files, notes = open_run(runs, opts)
    for line in notes + ([] if resume else drfc_lines(drfc)):
        console.print(line, highlight=False, soft_wrap=True)
    envs = f" × {envs_per_worker} envs" if envs_per_worker > 1 else ""
    console.print(f"run [bold]{opts.run_id}[/]: {opts.workers} workers{envs} on {run.env.track}, store {store}")
    if teacher:
        from racer.teacher import split_time, train_with_teacher

        teacher_s = split_time(opts, parse_duration(teacher_time, "--teacher-time") if teacher_time else None)
        share_updates = min(DistillConfig.model_fields["teacher_share_updates"].default, distill_updates)
        settings = {"updates": distill_updates, "teacher_share_updates": share_updates, "fine_tune": fine_tune}
        status = train_with_teacher(
            runs, opts, (run, files), distill=settings, teacher_time_s=teacher_s, console=console
        )[1]
    else:
        status = run_train(run, opts, files, console)
    try:
        lines = [done_line(runs, run.run_id, status.get("trained_s", 0.0))]
        for line in [*lines, *run_summary(run.run_id, runs, store, s3_endpoint)]:
            console.print(line, highlight=False, soft_wrap=True)
    except UserError as exc:  # the run is trained and saved; only its description failed
        console.print(f"[yellow]could not read the run's summary: {exc}", highlight=False)


def check(
    reward_fn: RewardFn = None,
    action_space: ActionSpace = None,
    hyperparams: Hyperparams = None,
    track: TrackOpt = None,
    from_drfc: FromDrfc = None,
    race_type: RaceTypeOpt = None,
    race: RaceFile = None,
) -> None:
    """Validate DeepRacer files exactly as racer train would, start nothing, and say what racer does with each."""
    from racer.check import check_files, merge_inputs
    from racer.options import RunOptions
    from racer.runconfig import load_race

    race_config = load_race(race, race_type)
    flags = RunOptions.from_flags(
        track=track, reward_fn=reward_fn, action_space=action_space, hyperparams=hyperparams, race=race_config
    )
    opts, drfc = merge_inputs(flags, from_drfc)
    for line in check_files(opts, drfc):
        console.print(line, highlight=False, soft_wrap=True)
    console.print("ok: racer train would accept these files", highlight=False)
