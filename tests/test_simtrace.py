"""DeepRacer sim-traces: row format, the worker's CSVs and log lines, read back with deepracer-utils itself."""

import io
import json
import logging
import shutil
import time

import numpy as np
import pytest
import redis
from deepracer.logs import AnalysisUtils, DeepRacerLog, LogFolderType, S3FileHandler, SimulationLogsIO

from common.action_space import default_action_space
from common.defaults import DEFAULT_TRACK, STRAIGHT_TRACK
from common.simtrace import (
    COLUMNS,
    SimTraceRecorder,
    SimTraceWriter,
    row_from_step,
    simtrace_row,
)
from model_store import open_store
from model_store.runs import evaluation_stamp, simtrace_key
from sim.env import RacerEnv
from sim.track import load_track
from tests.conftest import S3_BUCKET
from tests.shared_data import shared_data
from tests.test_training_loop import fill, start

# The header of DeepRacer's own sim-trace CSVs (the simapp's training-simtrace files).
SOURCES_HEADER = (
    "episode,steps,X,Y,yaw,steer,throttle,action,reward,done,all_wheels_on_track,progress,closest_waypoint,"
    "track_len,tstamp,episode_status,pause_duration"
)
# Rows written by racer in DeepRacer's format: the prepare row of a discrete-action episode, a step, an episode's last
# row off the track, and a continuous-action step. Their values are racer's own; DeepRacer's own rows are read from
# its public logs in place (../shared/data, tests/shared_data.py) by the tests that compare with them.
_ROW = dict(done=False, all_wheels_on_track=True, track_len=17.6, episode_status="in_progress")
RACER_ROWS = [
    simtrace_row(**{**_ROW, **values})
    for values in (
        dict(episode=0, steps=1, x=1.23456789, y=-0.5, yaw_deg=12.345678, steer_deg=20.0, throttle=2.0, action=11)
        | dict(reward=0.0, progress=0.79146, closest_waypoint=1, tstamp=20.202, episode_status="prepare"),
        dict(episode=2, steps=3, x=4.5, y=0.25, yaw_deg=-0.125, steer_deg=30.0, throttle=2.0, action=13, reward=1.0)
        | dict(progress=0.875, closest_waypoint=13, tstamp=24.204),
        dict(episode=19, steps=26, x=4.0, y=0.03125, yaw_deg=-43.5, steer_deg=-20.0, throttle=1.0, action=2)
        | dict(reward=0.001, done=True, all_wheels_on_track=False, progress=11.5, closest_waypoint=8, tstamp=56.002)
        | dict(episode_status="off_track"),
        dict(episode=0, steps=2, x=-1.5, y=-1.75, yaw_deg=179.0, steer_deg=4.123456789012345, throttle=2.0)
        | dict(action=(4.123456789012345, 2.0), reward=0.84375, progress=0.84375, closest_waypoint=1, tstamp=36.231),
    )
]
DEEPRACER_LOGS = {
    "ros1": ("gazebo-ros1-console2022-reinvent_base", "27-iteration.csv"),  # discrete actions, laps completed
    "ros2": ("gazebo-ros2-simapp6-reInvent2019_wide_cw", "0-iteration.csv"),  # 2026: continuous actions, 19 columns
}


def deepracer_lines(which: str) -> list[str]:
    """The rows (without header) of one of DeepRacer's own training sim-traces, their first 17 columns."""
    folder, name = DEEPRACER_LOGS[which]
    lines = shared_data("logs", folder, "training-simtrace", name).read_text().splitlines()
    return [",".join(line.split(",")[:17]) for line in lines[1:]]


# deepracer-utils' names for the columns it loads from a sim-trace folder.
LOADED_COLUMNS = {
    "episode",
    "steps",
    "x",
    "y",
    "yaw",
    "steering_angle",
    "speed",
    "action",
    "reward",
    "done",
    "on_track",
    "progress",
    "closest_waypoint",
    "track_len",
    "tstamp",
    "episode_status",
    "pause_duration",
    "wall_clock",
    "iteration",
    "worker",
    "unique_episode",
}


def _rebuild(line: str) -> list[str]:
    """A DeepRacer row rebuilt through simtrace_row from its parsed values."""
    v = line.split(",")
    action = [float(a) for a in v[7][1:-1].split()] if v[7].startswith("[") else int(v[7])
    return simtrace_row(
        episode=int(v[0]),
        steps=int(float(v[1])),
        x=float(v[2]),
        y=float(v[3]),
        yaw_deg=float(v[4]),
        steer_deg=float(v[5]),
        throttle=float(v[6]),
        action=action,
        reward=float(v[8]),
        done=v[9] == "True",
        all_wheels_on_track=v[10] == "True",
        progress=float(v[11]),
        closest_waypoint=int(v[12]),
        track_len=float(v[13]),
        tstamp=float(v[14]),
        episode_status=v[15],
        pause_duration=float(v[16]),
    )


# --- format -------------------------------------------------------------------------------------------------------


def test_header_is_the_documented_one():
    assert ",".join(COLUMNS) == SOURCES_HEADER
    assert SimTraceWriter().csv_text() == SOURCES_HEADER + "\n"


@pytest.mark.parametrize("which", list(DEEPRACER_LOGS))
def test_rows_are_written_character_for_character_like_deepracer(which):
    """Every row of one of DeepRacer's sim-traces, parsed and written again by simtrace_row, is the same text, but
    for two things DeepRacer writes differently and its tools read alike: ``progress`` of a completed lap (DeepRacer
    writes the integer ``100``, racer ``100.0``) and a ``tstamp`` with a float sum's noise (``48.846000000000004``,
    racer ``48.846``: the simapp's clock, to the millisecond)."""
    lines = deepracer_lines(which)
    same = 0
    for line in lines:
        theirs, ours = line.split(","), _rebuild(line)
        for i in np.flatnonzero([a != b for a, b in zip(theirs, ours, strict=True)]):
            if COLUMNS[i] == "progress":
                assert (theirs[i], ours[i], theirs[15]) == ("100", "100.0", "lap_complete"), line
            else:
                assert COLUMNS[i] == "tstamp" and float(ours[i]) == round(float(theirs[i]), 3), line
        same += theirs == ours
    assert same > 0.99 * len(lines) and len(lines) > 300


def test_log_line_uses_the_simapp_printf_and_parses_with_deepracer_utils():
    # The simapp: 'SIM_TRACE_LOG:%d,%d,%.4f,%.4f,%.4f,%.2f,%.2f,%s,%.4f,%s,%s,%.4f,%d,%.2f,%s,%s,%.2f'
    rows = [_rebuild(",".join(row)) for row in RACER_ROWS]
    assert rows == RACER_ROWS
    lines = [SimTraceWriter.log_line(r) for r in rows]
    assert lines[0] == (
        "SIM_TRACE_LOG:0,1,1.2346,-0.5000,12.3457,20.00,2.00,11,0.0000,False,True,0.7915,1,17.60,20.202,prepare,0.00"
    )
    assert lines[3].split(",")[7] == "[4.123456789012345 2.0]"
    log_text = "".join(f"2026-01-01 00:00:00,000 racer.simtrace INFO {line}\n" for line in lines)
    df = SimulationLogsIO.convert_to_pandas(SimulationLogsIO.load_buffer(io.StringIO(log_text)))
    assert df["episode"].tolist() == [0, 2, 19, 0] and df["steps"].tolist() == [1, 3, 26, 2]
    assert df["action"].tolist() == [11, 13, 2, -1]  # deepracer-utils' own value for a continuous action
    assert df["done"].tolist() == [False, False, True, False] and df["on_track"].tolist() == [True, True, False, True]
    assert df["episode_status"].tolist() == ["prepare", "in_progress", "off_track", "in_progress"]
    assert np.allclose(df["x"], [float(r[2]) for r in rows], atol=1e-4)
    assert np.allclose(df["tstamp"], [float(r[14]) for r in rows])


def test_simtrace_keys():
    assert simtrace_key("r1", "training", 7, 2) == "runs/r1/2/training-simtrace/7-iteration.csv"
    stamp = evaluation_stamp(0.0)
    assert stamp == "19700101000000"
    assert (
        simtrace_key("r1", "evaluation", 0, evaluation=stamp)
        == "runs/r1/evaluation-19700101000000/evaluation-simtrace/0-iteration.csv"
    )
    for bad in [
        dict(run_id="a/b", kind="training", iteration=0),
        dict(run_id="r", kind="training", iteration=-1),
        dict(run_id="r", kind="training", iteration=0, worker="w0"),
        dict(run_id="r", kind="evaluation", iteration=0),
        dict(run_id="r", kind="evaluation", iteration=0, evaluation="2026"),
        dict(run_id="r", kind="testing", iteration=0),
    ]:
        with pytest.raises(ValueError):
            simtrace_key(**bad)


def _info(steps, x, status="in_progress", command=(0.0, 1.0)):
    """An env ``info`` after ``steps`` env steps (``params["steps"]`` counts DeepRacer's prepare step too)."""
    params = {
        "x": x,
        "y": 0.0,
        "heading": 0.0,
        "steps": steps + 1,
        "progress": 10.0 * steps,
        "all_wheels_on_track": True,
        "waypoints": [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0)],
        "closest_waypoints": [0, 1],
        "track_length": 2.0,
        "sim_time": steps / 15,
    }
    return {"params": params, "episode_status": status, "command": command}


def test_recorder_pairs_each_pose_with_the_action_chosen_there():
    rec = SimTraceRecorder()
    rec.reset(_info(0, 0.0, "prepare"), episode=4)
    rec.step(3, _info(1, 0.1, command=(15.0, 1.0)), 0.5, False)
    rec.step(5, _info(2, 0.7, "off_track", command=(-15.0, 0.5)), 0.25, True)
    rows = [r.split(",") for r in rec.take().splitlines()[1:]]
    # episode, steps, X, steer, throttle, action, reward, done, closest_waypoint, status
    got = [(r[0], r[1], r[2], r[5], r[6], r[7], r[8], r[9], r[12], r[15]) for r in rows]
    assert got == [
        ("4", "1.0", "0.0", "15.0", "1.0", "3", "0.0", "False", "0", "prepare"),
        ("4", "2.0", "0.1", "-15.0", "0.5", "5", "0.5", "False", "0", "in_progress"),
        ("4", "3.0", "0.7", "-15.0", "0.5", "5", "0.25", "True", "1", "off_track"),  # repeats the last action
    ]
    assert rec.take() is None


def test_an_episode_in_progress_stays_for_the_next_iteration():
    rec = SimTraceRecorder()
    rec.reset(_info(0, 0.0, "prepare"), episode=0)
    rec.step(1, _info(1, 0.1), 1.0, True)
    rec.reset(_info(0, 0.0, "prepare"), episode=1)
    rec.step(2, _info(1, 0.1), 1.0, False)
    first = rec.take()
    assert [r.split(",")[0] for r in first.splitlines()[1:]] == ["0", "0"]
    last = rec.take(include_open=True)  # the worker's close(): the partial episode, its last pose included
    assert [r.split(",")[:2] for r in last.splitlines()[1:]] == [["1", "1.0"], ["1", "2.0"]]


def test_prepare_row_from_a_real_reset_and_continuous_actions(tmp_path):
    meta = tmp_path / "model_metadata.json"
    space = {"steering_angle": {"low": -20.0, "high": 20.0}, "speed": {"low": 0.5, "high": 1.5}}
    meta.write_text(json.dumps({"action_space": space, "action_space_type": "continuous"}))
    env = RacerEnv(track=STRAIGHT_TRACK, action_space=str(meta))
    rec = SimTraceRecorder()
    _, info = env.reset(seed=1)
    rec.reset(info, episode=0)
    _, reward, term, trunc, info2 = env.step(np.array([12.5, 0.7], np.float32))
    rec.step(np.array([12.5, 0.7], np.float32), info2, reward, term or trunc)
    rows = [r.split(",") for r in rec.take(include_open=True).splitlines()[1:]]
    assert rows[0][1] == "1.0" and rows[0][8] == "0.0" and rows[0][15] == "prepare"
    p = info["params"]
    assert float(rows[0][2]) == p["x"] and float(rows[0][3]) == p["y"]
    steer, speed = info2["command"]
    assert rows[0][7] == f"[{steer!r} {speed!r}]" and float(rows[0][5]) == steer
    assert rows[1][1] == "2.0" and float(rows[1][8]) == pytest.approx(reward)
    assert row_from_step(info2, episode=0, action=0, reward=reward, done=False)[1] == "2.0"


# --- a real rollout, read with deepracer-utils ---------------------------------------------------------------------


class _Lines(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(f"{record.name} INFO {record.getMessage()}")


@pytest.fixture(scope="module")
def rollout(redis_server, tmp_path_factory):
    """One trainer iteration with one worker: 0-iteration.csv on the policy switch, 1-iteration.csv on close."""
    redis.Redis.from_url(redis_server.url).flushall()
    tmp = tmp_path_factory.mktemp("simtrace")
    hp = tmp / "hyperparameters.json"
    hp.write_text(json.dumps({"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2}))
    store, run_id = str(tmp / "store"), "simtrace-run"
    logger, handler = logging.getLogger("racer.simtrace"), _Lines()
    logger.addHandler(handler)
    old_level = logger.level
    logger.setLevel(logging.INFO)
    try:
        trainer, worker = start(run_id, redis_server.url, store, str(hp))
        fill(trainer, worker)
        trainer.train()
        assert worker.poll_policy() and worker.policy_version == 1
        worker.push(worker.collect())
        worker.close()
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)
    return {
        "dir": tmp / "store" / "runs" / run_id,
        "store": store,
        "run_id": run_id,
        "env_steps": worker.env_steps,
        "finished": worker.episodes,
        "lines": handler.lines,
    }


def _load(folder) -> tuple[DeepRacerLog, object]:
    log = DeepRacerLog(str(folder))
    log.load()
    return log, log.dataframe()


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_the_worker_writes_one_csv_per_iteration_in_drfcs_multi_worker_layout(rollout):
    files = sorted(p.relative_to(rollout["dir"]).as_posix() for p in rollout["dir"].rglob("*-iteration.csv"))
    assert files == ["0/training-simtrace/0-iteration.csv", "0/training-simtrace/1-iteration.csv"]
    first = (rollout["dir"] / files[0]).read_text().splitlines()
    assert first[0] == SOURCES_HEADER
    assert first[-1].split(",")[9] == "True"  # iteration 0 holds whole episodes only


def test_deepracer_utils_loads_the_run_folder(rollout):
    log, df = _load(rollout["dir"])
    assert log.fh.type == LogFolderType.DRFC_MODEL_MULTIPLE_WORKERS
    assert set(df.columns) == LOADED_COLUMNS
    assert sorted(df["iteration"].unique()) == [0, 1] and set(df["worker"]) == {0}
    prepares = int((df["episode_status"] == "prepare").sum())
    assert len(df) == rollout["env_steps"] + prepares  # one row per step plus each episode's prepare row
    assert prepares == df["episode"].nunique() and prepares in (rollout["finished"], rollout["finished"] + 1)


def test_episodes_are_consistent(rollout):
    _, df = _load(rollout["dir"])
    actions = default_action_space()
    for _, ep in df.groupby(["worker", "episode"]):
        ep = ep.sort_values("steps")
        assert ep["steps"].tolist() == [float(s) for s in range(1, len(ep) + 1)]
        assert ep["episode_status"].iloc[0] == "prepare" and (ep["episode_status"].iloc[1:] != "prepare").all()
        assert ep["reward"].iloc[0] == 0.0 and not ep["done"].iloc[:-1].any()
        assert ep["iteration"].nunique() == 1  # an episode is never split across iterations
        assert (np.diff(ep["tstamp"]) > 0).all()
    finished = df.groupby(["worker", "episode"])["done"].any()
    assert finished.sum() >= 2  # num_episodes_between_training
    for a, steer, speed in df[["action", "steering_angle", "speed"]].itertuples(index=False):
        assert (steer, speed) == actions.command(a)
    assert df["progress"].between(0, 100).all()
    track = load_track(STRAIGHT_TRACK)
    borders = track.waypoints[:, 2:].reshape(-1, 2)
    margin = 0.5  # the logged point is 0.14 m ahead of the car, which may be past the border when it goes off
    assert df["x"].between(borders[:, 0].min() - margin, borders[:, 0].max() + margin).all()
    assert df["y"].between(borders[:, 1].min() - margin, borders[:, 1].max() + margin).all()
    assert np.allclose(df["track_len"], track.length)


def test_deepracer_utils_reads_our_columns_as_it_reads_deepracers(rollout, tmp_path):
    (tmp_path / "training-simtrace").mkdir()
    lines = deepracer_lines("ros1")
    discrete = "\n".join([SOURCES_HEADER, *lines[: lines.index(next(x for x in lines if ",True," in x)) + 1]]) + "\n"
    (tmp_path / "training-simtrace" / "0-iteration.csv").write_text(discrete)
    _, theirs = _load(tmp_path)
    _, ours = _load(rollout["dir"])
    assert ours.dtypes.to_dict() == theirs.dtypes.to_dict()


def test_deepracer_utils_summaries_run(rollout):
    _, df = _load(rollout["dir"])
    episodes = df.groupby(["iteration", "episode"]).ngroups
    agg = AnalysisUtils.simulation_agg(df)
    assert len(agg) == episodes
    assert agg["progress"].between(0, 100).all() and (agg["time"] > 0).all()
    assert len(AnalysisUtils.simulation_agg(df, secondgroup="unique_episode")) >= 1
    sizes = df.groupby(["iteration", "episode"]).size().sort_index()
    assert agg.set_index(["iteration", "episode"])["steps"].sort_index().tolist() == sizes.tolist()
    log, _ = _load(rollout["dir"])
    stability = log.stability.analyze()
    assert len(stability) >= 1


def test_worker_log_lines_match_the_csv_rows(rollout):
    lines = [line for line in rollout["lines"] if "SIM_TRACE_LOG:" in line]
    logged = SimulationLogsIO.convert_to_pandas(SimulationLogsIO.load_buffer(io.StringIO("\n".join(lines))))
    _, df = _load(rollout["dir"])
    df = df.sort_values(["episode", "steps"]).reset_index(drop=True)
    logged = logged.sort_values(["episode", "steps"]).reset_index(drop=True)
    assert len(logged) == len(df)
    assert (logged["episode"] == df["episode"]).all() and (logged["steps"] == df["steps"]).all()
    assert (logged["action"] == df["action"]).all() and (logged["episode_status"] == df["episode_status"]).all()
    assert np.allclose(logged["x"], df["x"], atol=1e-4) and np.allclose(logged["progress"], df["progress"], atol=1e-4)


def test_the_policy_switch_upload_is_small_and_fast(rollout, tmp_path):
    # At a policy switch the worker puts one CSV of the iteration's rows: about 200 bytes a step.
    text = (rollout["dir"] / "0" / "training-simtrace" / "0-iteration.csv").read_bytes()
    assert len(text) < 250 * (rollout["env_steps"] + 50)
    store = open_store(str(tmp_path))
    t0 = time.perf_counter()
    store.put(simtrace_key(rollout["run_id"], "training", 0, 0), text)
    assert time.perf_counter() - t0 < 0.05


def test_evaluation_simtrace_loads_as_an_evaluation(rollout, tmp_path):
    folder = tmp_path / "runs" / "run"
    shutil.copytree(rollout["dir"], folder)
    env = RacerEnv(track=STRAIGHT_TRACK)
    rec, rng = SimTraceRecorder(), np.random.default_rng(0)
    for episode in range(2):
        _, info = env.reset(seed=episode)
        rec.reset(info, episode)
        done = False
        while not done:
            action = int(rng.integers(env.action_space.n))
            _, reward, term, trunc, info = env.step(action)
            done = term or trunc
            rec.step(action, info, reward, done)
    key = simtrace_key("run", "evaluation", 0, evaluation=evaluation_stamp(time.time()))
    target = tmp_path / key
    target.parent.mkdir(parents=True)
    target.write_text(rec.take())
    log = DeepRacerLog(str(folder))
    log.load_evaluation_trace()
    df = log.dataframe()
    assert df["episode"].nunique() == 2 and (df.groupby("episode")["episode_status"].first() == "prepare").all()
    agg = AnalysisUtils.simulation_agg(df, firstgroup="stream", is_eval=True)
    assert len(agg) == 2


def test_deepracer_utils_reads_the_run_from_s3(rollout, s3_server):
    prefix = f"it-{rollout['run_id']}"
    store = open_store(f"s3://{S3_BUCKET}/{prefix}", s3_server)
    for path in rollout["dir"].rglob("*-iteration.csv"):
        store.put(path.relative_to(rollout["dir"].parent.parent).as_posix(), path.read_bytes())
    handler = S3FileHandler(bucket=S3_BUCKET, prefix=f"{prefix}/runs/{rollout['run_id']}", s3_endpoint_url=s3_server)
    log = DeepRacerLog(filehandler=handler)
    assert handler.type == LogFolderType.DRFC_MODEL_MULTIPLE_WORKERS
    log.load()
    _, local = _load(rollout["dir"])
    assert len(log.dataframe()) == len(local)


def test_deepracer_utils_loads_an_object_avoidance_evaluation(rollout, tmp_path):
    # The 18th column of a race with objects (the simapp's obstacle_crash_counter) is read, and dropped, by
    # deepracer-utils' DeepRacerLog as it reads DeepRacer's own OA sim-traces.
    from common.race import RaceConfig
    from common.simtrace import OBSTACLE_COLUMN

    folder = tmp_path / "runs" / "run"
    shutil.copytree(rollout["dir"], folder)
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", object_avoidance={"number_of_obstacles": 3})
    env = RacerEnv(track=DEFAULT_TRACK, race=race)
    rec, rng = SimTraceRecorder(), np.random.default_rng(0)
    for episode in range(2):
        _, info = env.reset(seed=episode)
        rec.reset(info, episode)
        done = False
        while not done:
            action = int(rng.integers(env.action_space.n))
            _, reward, term, trunc, info = env.step(action)
            done = term or trunc
            rec.step(action, info, reward, done)
    text = rec.take()
    assert text.splitlines()[0].endswith(f",pause_duration,{OBSTACLE_COLUMN}")
    target = tmp_path / simtrace_key("run", "evaluation", 0, evaluation=evaluation_stamp(time.time()))
    target.parent.mkdir(parents=True)
    target.write_text(text)
    log = DeepRacerLog(str(folder))
    log.load_evaluation_trace()
    df = log.dataframe()
    assert df["episode"].nunique() == 2 and set(df.columns) >= LOADED_COLUMNS - {"worker", "unique_episode"}
