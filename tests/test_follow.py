"""A run you can follow without a terminal, and the CLI's frictions a new user met (issue 44): one test per friction,
and a real ``racer train`` piped through ``cat`` that prints progress while ``racer status`` answers beside it."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import redis
from rich.table import Table
from typer.testing import CliRunner

from common.bus import Bus
from common.defaults import STRAIGHT_TRACK
from common.protocol import EvaluationSummary
from model_store import LocalStore, RunStore, pointer_key
from racer.cli import app

ROOT = Path(__file__).resolve().parents[1]
HP = {"batch_size": 64, "num_epochs": 1, "num_episodes_between_training": 4, "lr": 0.001, "discount_factor": 0.99}


def invoke(*args: str, **env: str):
    """``racer ARGS`` in this process, output captured as a pipe captures it (not a terminal)."""
    return CliRunner().invoke(app, list(args), env=env or None)


# --- README --------------------------------------------------------------------------------------------------------


def _bash_blocks(text: str) -> list[list[str]]:
    return [block.splitlines() for block in re.findall(r"```bash\n(.*?)```", text, re.S)]


def test_readme_activates_the_virtualenv_before_its_first_bare_racer_command() -> None:
    """Its later commands (and a run's ``next:`` lines) are a bare ``racer``: on PATH only in the activated venv."""
    lines = [line.strip() for block in _bash_blocks((ROOT / "README.md").read_text()) for line in block]
    first_bare = next(i for i, line in enumerate(lines) if line.startswith("racer "))
    assert any("source .venv/bin/activate" in line or ". .venv/bin/activate" in line for line in lines[:first_bare])


def test_the_store_layout_in_the_docs_is_the_stores() -> None:
    """``latest.json`` and ``best.json`` are at ``runs/<id>/``, beside ``checkpoints/``, not in it."""
    assert pointer_key("r", "latest") == "runs/r/latest.json"
    for doc in ("README.md", "docs/training.md"):
        text = " ".join((ROOT / doc).read_text().split())
        assert "`runs/<id>/latest.json`" in text, doc
        checkpoints = text.split("checkpoints/000000007.pt", 1)[1].split(";", 1)[0]  # the checkpoints' own item
        assert "latest.json" not in checkpoints and "best.json" not in checkpoints, (doc, checkpoints)


# --- racer train --help --------------------------------------------------------------------------------------------


def test_train_help_shows_the_defaults_of_track_workers_and_time_limit() -> None:
    result = invoke("train", "--help", COLUMNS="200", TERMINAL_WIDTH="200")
    assert result.exit_code == 0
    text = " ".join(result.output.replace("│", " ").split())
    assert re.search(r"\[default: \(?racer_loop\)?\]", text) and re.search(r"\[default: \(?2\)?\]", text), text
    assert "until Ctrl-C" in text


def test_no_option_help_hides_text_in_brackets_that_rich_would_swallow() -> None:
    """Rich reads ``[default: 2]`` in a help text as markup and prints nothing of it: defaults go in show_default."""
    import typer.main

    group = typer.main.get_command(app)

    def commands(cmd, path):
        yield path, cmd
        for name, sub in getattr(cmd, "commands", {}).items():
            yield from commands(sub, f"{path} {name}")

    swallowed = [
        f"{path} {param.opts[0] if getattr(param, 'opts', None) else param.name}"
        for path, cmd in commands(group, "racer")
        for param in cmd.params
        if re.search(r"\[[a-z][^\]]*\]", getattr(param, "help", None) or "")
    ]
    assert swallowed == []


# --- the end of a run ----------------------------------------------------------------------------------------------


def test_the_done_line_says_what_metrics_jsonl_says(tmp_path: Path) -> None:
    """The launcher's last status can be older than the last update (seen: ``done: 0 iterations, 864 env steps``
    while metrics.jsonl had iteration 1 and 1,152 steps): the line is read from the store once all has stopped."""
    from racer.launcher import done_line

    runs = RunStore(LocalStore(tmp_path))
    rows = [{"iteration": 1, "env_steps": 1152, "policy_version": 1}, {"iteration": 2, "env_steps": 2304}]
    runs.write_file("r", "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in rows))
    assert done_line(runs, "r", 61.4) == "done: 2 iterations, trained on 2,304 env steps in 61 s"
    runs.write_file("q", "config.json", "{}")
    assert done_line(runs, "q", 9.0) == "done: 0 iterations, trained on 0 env steps in 9 s"


# --- racer check --from-drfc ---------------------------------------------------------------------------------------


def test_check_from_drfc_prints_a_table_naming_each_mapped_value(tmp_path: Path) -> None:
    unused = [f"DR_UNUSED_SETTING_NUMBER_{k}" for k in range(40)]
    (tmp_path / "run.env").write_text(
        "DR_WORLD_NAME=racer_loop\nDR_RACE_TYPE=OBJECT_AVOIDANCE\nDR_OA_NUMBER_OF_OBSTACLES=3\n"
        "DR_H2B_NUMBER_OF_BOT_CARS=2\nDR_EVAL_OFF_TRACK_PENALTY=3.0\nDR_TRAIN_CHANGE_START_POSITION=True\n"
        "DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST=0.1\nDR_LOCAL_S3_PRETRAINED=False\n"
        "DR_LOCAL_S3_PRETRAINED_PREFIX=rl-sagemaker-pretrained\n" + "".join(f"{k}=x\n" for k in unused)
    )
    result = invoke("check", "--from-drfc", str(tmp_path))
    assert result.exit_code == 0, result.output
    out = result.output
    assert "(below)" not in out
    rows = {line.split()[0]: line for line in out.splitlines() if line.startswith("  DR_")}
    assert re.search(
        r"DR_OA_NUMBER_OF_OBSTACLES +3 +object_avoidance.number_of_obstacles 3$", rows["DR_OA_NUMBER_OF_OBSTACLES"]
    )
    assert "not used: the race is OBJECT_AVOIDANCE" in rows["DR_H2B_NUMBER_OF_BOT_CARS"]
    assert "penalties.off_track_penalty 3" in rows["DR_EVAL_OFF_TRACK_PENALTY"]
    assert "round_robin_divisions 10" in rows["DR_TRAIN_ROUND_ROBIN_ADVANCE_DIST"]
    assert "--track racer_loop" in rows["DR_WORLD_NAME"]
    assert "not used" in rows["DR_LOCAL_S3_PRETRAINED_PREFIX"] and "DR_LOCAL_S3_PRETRAINED" in rows
    assert max(len(line) for line in out.splitlines() if "DR_" in line) <= 120  # no 1.5 kB lines
    listed = " ".join(line for line in out.splitlines() if "DR_UNUSED" in line)
    assert all(name in listed for name in unused) and "no racer meaning, not used:" in out


def test_each_drfc_race_variable_names_the_field_race_config_from_drfc_sets() -> None:
    from common.race import race_config_from_drfc
    from racer.drfc import RACE_FIELDS

    samples = {
        "DR_OA_NUMBER_OF_OBSTACLES": "3",
        "DR_OA_MIN_DISTANCE_BETWEEN_OBSTACLES": "1.5",
        "DR_OA_RANDOMIZE_OBSTACLE_LOCATIONS": "False",
        "DR_OA_IS_OBSTACLE_BOT_CAR": "True",
        "DR_OA_OBSTACLE_TYPE": "amazon_box_obstacle",
        "DR_OA_OBJECT_POSITIONS": "0.2,1;0.6,-1",
        "DR_H2B_IS_LANE_CHANGE": "True",
        "DR_H2B_LOWER_LANE_CHANGE_TIME": "2.5",
        "DR_H2B_UPPER_LANE_CHANGE_TIME": "6.5",
        "DR_H2B_LANE_CHANGE_DISTANCE": "1.5",
        "DR_H2B_NUMBER_OF_BOT_CARS": "2",
        "DR_H2B_MIN_DISTANCE_BETWEEN_BOT_CARS": "3.5",
        "DR_H2B_RANDOMIZE_BOT_CAR_LOCATIONS": "True",
        "DR_H2B_BOT_CAR_SPEED": "0.5",
        "DR_H2B_BOT_CAR_PENALTY": "4.5",
        "DR_EVAL_OFF_TRACK_PENALTY": "3.5",
        "DR_COLLISION_PENALTY": "2.5",
        "DR_EVAL_MAX_RESETS": "7",
        "DR_EVAL_RESET_BEHIND_DIST": "0.5",
    }
    assert set(samples) == set(RACE_FIELDS)
    for key, (section, name) in RACE_FIELDS.items():
        race_type = {"object_avoidance": "OBJECT_AVOIDANCE", "head_to_bot": "HEAD_TO_BOT"}.get(section, "TIME_TRIAL")
        base = race_config_from_drfc({"DR_RACE_TYPE": race_type}, evaluation=True).model_dump()
        given = race_config_from_drfc({"DR_RACE_TYPE": race_type, key: samples[key]}, evaluation=True).model_dump()
        changed = {(s, n) for s in base if isinstance(base[s], dict) for n in base[s] if base[s][n] != given[s][n]}
        assert changed == {(section, name)}, key


# --- tables, piped -------------------------------------------------------------------------------------------------


def test_models_ls_wide_piped_keeps_every_column(tmp_path: Path) -> None:
    runs = RunStore(LocalStore(tmp_path))
    long_id = "a-rather-long-run-name-for-the-spring-2027-league-final-attempt-number-42"
    for v in (1, 12345):
        runs.save_checkpoint(long_id, v, b"w" * 1000, {"env_steps": 1_234_567 * v, "created": 1.8e9})
    result = invoke("models", "ls", "--store", str(tmp_path), "--wide")
    assert result.exit_code == 0, result.output
    assert "…" not in result.output
    rows = [line for line in result.output.splitlines() if line.startswith(long_id)]
    assert len(rows) == 2 and rows[1].split()[1] == "12345", rows


def test_a_piped_table_is_printed_whole(capsys) -> None:
    from racer.commands.evaluate import _trials_table
    from racer.commands.options import print_table

    trial = {"track": "2022_april_pro_ccw_with_a_long_name", "reverse": True, "start_index": 117}
    trial |= {"status": "lap_complete", "progress": 100.0, "steps": 1234, "lap_time_s": 82.27}
    trial |= {"resets": 3, "penalty_s": 15.0}
    print_table(_trials_table([trial]))
    out = capsys.readouterr().out
    assert "…" not in out and "2022_april_pro_ccw_with_a_long_name" in out and "3 (+15 s)" in out
    assert "82.27" in out and "lap_complete" in out
    wide = Table("a" * 70, "b" * 70)
    wide.add_row("x", "y")
    print_table(wide)
    assert "a" * 70 in capsys.readouterr().out


# --- racer eval --video --------------------------------------------------------------------------------------------


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_eval_video_holds_every_trial_or_the_one_chosen_and_says_where(tmp_path: Path) -> None:
    import cv2

    from common.policy import action_space_spec, build_policy
    from common.weights import checkpoint_to_bytes
    from racer.runconfig import build_run
    from sim.env import RacerEnv

    run, files = build_run("vid", track=STRAIGHT_TRACK)
    runs = RunStore(LocalStore(tmp_path))
    for name, data in files.items():
        runs.write_file("vid", name, data)
    runs.write_config(run)
    model = build_policy((120, 160, 1), action_space_spec(RacerEnv(track=STRAIGHT_TRACK).actions), run.policy)
    runs.save_checkpoint("vid", 1, checkpoint_to_bytes(model.state_dict()), {"env_steps": 100})
    base = ["eval", "--run-id", "vid", "--store", str(tmp_path), "--checkpoint", "1", "--episodes", "1"]

    video = tmp_path / "all.mp4"
    result = invoke(*base, "--video", str(video), "--json", str(tmp_path / "all.json"))
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "all.json").read_text())
    frames = int(cv2.VideoCapture(str(video)).get(cv2.CAP_PROP_FRAME_COUNT))
    assert frames == sum(t["steps"] + 1 for t in record["trials"]) == record["video"]["frames"]
    said = " ".join(result.output.split())
    assert f"wrote {video}: all 2 trials" in said, said
    assert [t["steps"] for t in record["video"]["trials"]] == [t["steps"] for t in record["trials"]]

    one = tmp_path / "two.mp4"
    result = invoke(*base, "--video", str(one), "--video-trial", "2", "--json", str(tmp_path / "two.json"))
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "two.json").read_text())
    second = record["trials"][1]
    assert int(cv2.VideoCapture(str(one)).get(cv2.CAP_PROP_FRAME_COUNT)) == second["steps"] + 1
    assert f"wrote {one}: trial 2 of 2 (reverse from start {second['start_index']}" in " ".join(result.output.split())

    bad = invoke(*base, "--video", str(one), "--video-trial", "3")
    assert bad.exit_code == 2 and "--video-trial 3" in bad.output and "2 trials" in bad.output


# --- racer status finds the run ------------------------------------------------------------------------------------


def test_status_finds_a_running_train_by_its_run_id_or_its_store_alone(tmp_path: Path, redis_url: str) -> None:
    from racer.redis_record import redis_record_path, remove_redis_record, write_redis_record

    store = str(tmp_path)
    bus = Bus(redis.Redis.from_url(redis_url), "live")
    bus.set_trainer_status({"iteration": 3, "env_steps": 4096, "steps_per_s": 50.0})
    path = write_redis_record(store, "live", redis_url)  # this process plays the launcher
    assert json.loads(path.read_text())["pid"] == os.getpid() and (path.stat().st_mode & 0o777) == 0o600
    by_id = invoke("status", "--run-id", "live", "--store", store)
    assert by_id.exit_code == 0, by_id.output
    assert "run live" in by_id.output and "trainer: iteration 3, 4,096 env steps" in by_id.output
    # A record whose launcher is gone (killed) is ignored: the newest live one is found from the store alone.
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = redis_record_path(store, "stale")
    stale.parent.mkdir(parents=True)
    stale.write_text(json.dumps({"url": "unix:///nowhere.sock", "pid": dead.pid, "started": time.time() + 60}))
    alone = invoke("status", "--store", store)
    assert alone.exit_code == 0 and "run live" in alone.output, alone.output
    gone = invoke("status", "--run-id", "stale", "--store", store)
    assert gone.exit_code == 2 and "stale" in gone.output and "--redis" in gone.output
    remove_redis_record(path)
    assert not path.exists()
    none = invoke("status", "--store", store)
    assert none.exit_code == 2 and "no running racer train" in none.output


# --- TensorBoard ---------------------------------------------------------------------------------------------------


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_tensorboard_gets_the_evaluation_scalars(tmp_path: Path, redis_url: str, run_id: str) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from common.deadline import Deadline
    from racer.runconfig import build_run
    from trainer.process import Trainer, TrainerOptions

    run, files = build_run(run_id, track=STRAIGHT_TRACK)
    store = str(tmp_path / "store")
    trainer = Trainer(run, TrainerOptions(redis_url, store, run_files=files))
    trainer.start()
    trainer.opts.deadline = Deadline.after(1.5)
    for version, lap in ((1, None), (2, 9.5)):
        trainer.bus.report_evaluation(
            EvaluationSummary(
                version=version,
                env_steps=1000 * version,
                completion_rate=0.5 * version,
                mean_progress=60.0 * version / 2 + 40,
                best_lap_s=lap,
                mean_lap_s=None if lap is None else lap + 1,
                off_track=2 - version,
                score=50.0 * version,
                best=True,
            )
        )
    trainer.run_forever()  # reads them within its once-a-second housekeeping
    trainer.tb.flush()
    events = EventAccumulator(str(tmp_path / "store" / "runs" / run_id / "tensorboard"))
    events.Reload()
    scalars = {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}
    assert scalars["evaluation/completion_rate"] == [(1000, 0.5), (2000, 1.0)]
    assert scalars["evaluation/score"] == [(1000, 50.0), (2000, 100.0)]
    assert scalars["evaluation/best_lap_s"] == [(2000, 9.5)] and scalars["evaluation/mean_lap_s"] == [(2000, 10.5)]
    trainer.tb.close()


# --- a real run, piped ---------------------------------------------------------------------------------------------


@pytest.mark.slow("a 70 s racer train")
def test_train_piped_prints_progress_and_status_answers_from_another_process(tmp_path: Path) -> None:
    """``racer train --time-limit 70s 2>&1 | cat``: progress lines while it runs (not one line at the end), where its
    Redis is, ``racer status --run-id ID`` answering from a second process, and a summary matching metrics.jsonl."""
    (tmp_path / "hp.json").write_text(json.dumps(HP))
    cmd = [sys.executable, "-m", "racer", "train", "--workers", "1", "--track", STRAIGHT_TRACK, "--run-id", "piped"]
    cmd += ["--hyperparams", "hp.json", "--time-limit", "70s", "--no-eval"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    record = tmp_path / "runs" / "piped" / "redis.json"
    lines: list[tuple[float, str]] = []
    started = time.monotonic()
    status = None
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append((time.monotonic() - started, line.rstrip("\n")))
        if status is None and line.startswith("[") and "iter " in line:  # a progress line with the trainer's figures
            assert record.exists()
            status = subprocess.run(
                [sys.executable, "-m", "racer", "status", "--run-id", "piped"],
                cwd=tmp_path,
                capture_output=True,
                text=True,
                timeout=60,
            )
    assert proc.wait(timeout=120) == 0, "\n".join(text for _, text in lines)
    out = "\n".join(text for _, text in lines)
    progress = [(t, text) for t, text in lines if re.match(r"\[[0-9hms]+, [0-9hms]+ left\] ", text)]
    # At 30 s, 60 s and the last one: printed as it happened (not all at the end), at least once a minute.
    assert len(progress) >= 3, out
    times = [0.0] + [t for t, _ in progress]
    assert max(b - a for a, b in zip(times, times[1:], strict=False)) < 45, (times, out)
    assert re.search(r"^Redis (6\.2|7)\.[0-9.]+: unix://\S+redis.sock", out, re.M), out
    assert status is not None and status.returncode == 0, (status and status.stdout + status.stderr, out)
    assert "run piped" in status.stdout, status.stdout
    assert re.search(
        r"trainer: (collecting segments|updating policy v\d+ \(PPO update running for \d+ s\)); iteration",
        status.stdout,
    ), status.stdout
    assert not record.exists(), "the record of a stopped run's Redis is removed"
    rows = RunStore(LocalStore(tmp_path)).read_metrics("piped", missing_ok=True)
    last = rows[-1] if rows else {"iteration": 0, "env_steps": 0}
    done = next(text for _, text in lines if text.startswith("done: "))
    assert done.startswith(f"done: {last['iteration']} iterations, trained on {last['env_steps']:,} env steps in "), (
        done,
        rows,
    )
