"""racer.plots: training curves and evaluation trajectories as PNGs, read from a run folder through the store."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from common.defaults import DEFAULT_TRACK
from common.errors import OptionError, UserError
from model_store import LocalStore, ObjectStore, RunStore, open_store
from racer.cli import app
from racer.commands.options import checkpoint_choice
from racer.plots import (
    DPI,
    TRAINING_FIGSIZE,
    TRAJECTORY_FIGSIZE,
    plot_run,
    plot_training,
    plot_trajectories,
)
from sim.track import load_track
from tests.conftest import S3_BUCKET

TRACK = DEFAULT_TRACK


def fake_metrics(n: int = 10) -> list[dict]:
    """Rows shaped like the trainer's metrics.jsonl, with a learning curve that rises."""
    rng = np.random.default_rng(0)
    return [
        {
            "iteration": i,
            "policy_version": i,
            "env_steps": 450 * i,
            "episodes": 10,
            "mean_progress": min(100.0, 8.0 * i + rng.uniform(0, 5)),
            "mean_reward": 3.0 * i + rng.normal(0, 1),
            "laps_completed": max(0, i - 6),
            "time": 1_700_000_000.0 + 6 * i,
        }
        for i in range(1, n + 1)
    ]


def fake_trial(track_name: str, start: int, points: int, status: str, reverse: bool = False) -> dict:
    """A trial that runs beside the centre line from waypoint ``start`` for ``points`` waypoints, speeding up.

    It keeps a quarter of the way to the inner border, so that it is drawn on the road, off the centre line's dashes.
    """
    track = load_track(track_name)
    center = (0.75 * track.center + 0.25 * track.inner)[:-1]  # the last waypoint repeats the first: closed track
    idx = (start + np.arange(points)) % len(center)
    speed = np.linspace(0.5, 3.5, points)
    trajectory = [[float(x), float(y), float(v)] for (x, y), v in zip(center[idx], speed, strict=True)]
    return {
        "track": track_name,
        "reverse": reverse,
        "start_index": start,
        "progress": 100.0 * points / len(center),
        "status": status,
        "steps": points * 4,
        "lap_time_s": points * 4 / 15 if status == "lap_complete" else None,
        "trajectory": trajectory,
    }


def fake_evaluation(run_id: str, version: int, trials: list[dict]) -> dict:
    """An evaluation file as the evaluator writes it, consistent with its trials."""
    laps = [t["lap_time_s"] for t in trials if t["status"] == "lap_complete"]
    return {
        "run_id": run_id,
        "version": version,
        "env_steps": 450 * version,
        "track": TRACK,
        "episodes": len(trials),
        "completion_rate": len(laps) / len(trials),
        "mean_progress": float(np.mean([t["progress"] for t in trials])),
        "lap_times_s": laps,
        "best_lap_s": min(laps) if laps else None,
        "off_track": sum(t["status"] == "off_track" for t in trials),
        "score": len(laps) / len(trials),
        "trials": trials,
    }


def write_run(root: Path | ObjectStore, run_id: str, metrics: bool = True, evaluations: bool = True) -> RunStore:
    """A run (in a LocalStore at ``root``, or in the store given) with metrics.jsonl (10 iterations) and evaluations
    of checkpoints 4 and 8."""
    runs = RunStore(root if isinstance(root, ObjectStore) else LocalStore(root))
    runs.write_file(run_id, "config.json", "{}")
    if metrics:
        runs.write_file(run_id, "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in fake_metrics()))
    if evaluations:
        n = len(load_track(TRACK).center) - 1
        early = [fake_trial(TRACK, 0, 30, "off_track"), fake_trial(TRACK, 60, 20, "off_track")]
        late = [fake_trial(TRACK, 0, n + 1, "lap_complete"), fake_trial(TRACK, 40, 70, "off_track")]
        late.append(fake_trial(TRACK, 90, 10, "immobilized"))
        for version, trials in ((4, early), (8, late)):
            body = json.dumps(fake_evaluation(run_id, version, trials))
            runs.write_file(run_id, f"evaluations/{version:09d}.json", body)
    return runs


def read_png(path: Path, figsize: tuple[float, float]) -> np.ndarray:
    """Decode a PNG and check its size and that it is not blank; return it as RGB."""
    assert path.is_file()
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, f"{path} does not decode"
    assert img.shape == (round(figsize[1] * DPI), round(figsize[0] * DPI), 3)
    assert img.std() > 10
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def coloured_fraction(rgb: np.ndarray) -> float:
    """Fraction of strongly coloured pixels (channels far apart), which grey, white and black never are."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return float(((abs(r - g) > 60) | (abs(g - b) > 60)).mean())


def test_plot_training(tmp_path, run_id):
    runs = write_run(tmp_path / "store", run_id)
    out = plot_training(run_id, runs, tmp_path / "out" / "training.png")
    assert out == tmp_path / "out" / "training.png"
    read_png(out, TRAINING_FIGSIZE)


def test_plot_training_without_evaluations(tmp_path, run_id):
    runs = write_run(tmp_path / "store", run_id, evaluations=False)
    read_png(plot_training(run_id, runs, tmp_path / "training.png"), TRAINING_FIGSIZE)


def test_plot_training_without_metrics_names_the_run(tmp_path, run_id):
    runs = write_run(tmp_path / "store", run_id, metrics=False)
    with pytest.raises(UserError, match=run_id):
        plot_training(run_id, runs, tmp_path / "training.png")
    with pytest.raises(UserError, match="no-such-run"):
        plot_training("no-such-run", runs, tmp_path / "training.png")
    assert not (tmp_path / "training.png").exists()


def test_plot_trajectories_draws_coloured_paths_on_the_track(tmp_path, run_id):
    runs = write_run(tmp_path / "store", run_id)
    out = plot_trajectories(run_id, runs, tmp_path / "trajectories.png")
    rgb = read_png(out, TRAJECTORY_FIGSIZE)
    # The same figure with no trials is the baseline: the track alone (its centre line is yellow, so coloured too).
    empty = write_run(tmp_path / "empty", run_id, evaluations=False)
    evaluation = runs.read_evaluations(run_id)[-1]
    empty.write_file(run_id, "evaluations/000000008.json", json.dumps({**evaluation, "trials": []}))
    baseline = read_png(plot_trajectories(run_id, empty, tmp_path / "empty.png"), TRAJECTORY_FIGSIZE)
    assert coloured_fraction(baseline) < coloured_fraction(rgb)
    # Where the trajectories cross the dark grey road, pixels carry the colormap's colours instead.
    road = (np.abs(baseline.astype(int) - (48, 48, 52)).max(axis=2) < 12) & (baseline.std(axis=2) < 3)
    drawn = road & (np.abs(rgb.astype(int) - baseline.astype(int)).max(axis=2) > 60)
    # Lines 3 pt (~4 px) wide along the ~17 m lap that the late trials retrace, at ~75 px/m: ~5000 px (6029 measured).
    assert drawn.sum() > 2000
    assert coloured_fraction(rgb[drawn][None]) > 0.8


def test_plot_trajectories_picks_the_version(tmp_path, run_id):
    runs = write_run(tmp_path / "store", run_id)
    assert runs.evaluation_versions(run_id) == [4, 8]
    a = read_png(plot_trajectories(run_id, runs, tmp_path / "v4.png", version=4), TRAJECTORY_FIGSIZE)
    b = read_png(plot_trajectories(run_id, runs, tmp_path / "newest.png"), TRAJECTORY_FIGSIZE)
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 0.5  # different trials drawn
    # No best.json pointer yet: "best" is the best-scored evaluation, "latest" the newest.
    c = read_png(plot_trajectories(run_id, runs, tmp_path / "best.png", version="best"), TRAJECTORY_FIGSIZE)
    assert np.array_equal(b, c)
    with pytest.raises(UserError, match="checkpoint 5"):
        plot_trajectories(run_id, runs, tmp_path / "v5.png", version=5)


def test_plot_trajectories_without_evaluations_names_the_run(tmp_path, run_id):
    runs = write_run(tmp_path / "store", run_id, evaluations=False)
    with pytest.raises(UserError, match=run_id):
        plot_trajectories(run_id, runs, tmp_path / "trajectories.png")


def test_plot_run_writes_both(tmp_path, run_id):
    runs = write_run(tmp_path / "store", run_id)
    paths = plot_run(run_id, runs, tmp_path / "plots")
    assert [p.name for p in paths] == ["training.png", "trajectories.png"]
    read_png(paths[0], TRAINING_FIGSIZE)
    read_png(paths[1], TRAJECTORY_FIGSIZE)


def test_plot_run_skips_trajectories_without_evaluations(tmp_path, run_id, caplog):
    runs = write_run(tmp_path / "store", run_id, evaluations=False)
    paths = plot_run(run_id, runs, tmp_path / "plots")
    assert [p.name for p in paths] == ["training.png"]
    assert not (tmp_path / "plots" / "trajectories.png").exists()
    assert "no evaluations" in caplog.text


def test_malformed_evaluation_is_skipped(tmp_path, run_id):
    runs = write_run(tmp_path / "store", run_id)
    runs.write_file(run_id, "evaluations/000000009.json", "{not json")
    assert [e["version"] for e in runs.read_evaluations(run_id)] == [4, 8]
    read_png(plot_training(run_id, runs, tmp_path / "training.png"), TRAINING_FIGSIZE)


def test_plot_run_reads_an_s3_store(tmp_path, run_id, s3_server):
    runs = write_run(open_store(f"s3://{S3_BUCKET}/plots", endpoint=s3_server), run_id)
    paths = plot_run(run_id, runs, tmp_path)
    assert [p.name for p in paths] == ["training.png", "trajectories.png"]
    read_png(paths[1], TRAJECTORY_FIGSIZE)


# -- racer plot --checkpoint: the best checkpoint by default -----------------------------------------------------------


def write_run_with_checkpoints(root: Path, run_id: str) -> RunStore:
    """:func:`write_run` plus tiny checkpoints 4 and 8 (8 the latest) and the evaluator's ``best`` pointer on 4.

    The pointer, not the evaluation files' scores, is the evaluator's choice (8 scores higher here): only it can
    tell a plot of the best from one of the best-scored or the newest."""
    runs = write_run(root, run_id)
    for version in (4, 8):
        runs.save_checkpoint(run_id, version, f"weights-{version}".encode(), {"env_steps": 450 * version})
    runs.set_pointer(run_id, "best", 4)
    return runs


def plot_cli(store: Path, run_id: str, out: Path, *args: str):
    return CliRunner().invoke(app, ["plot", run_id, "--store", str(store), "--out", str(out), *args])


def test_racer_plot_draws_the_best_checkpoint_by_default(tmp_path, run_id):
    runs = write_run_with_checkpoints(tmp_path / "store", run_id)
    best = [c["version"] for c in runs.list_checkpoints(run_id) if c["best"]]
    assert best == [4] and runs.resolve(run_id, "latest") == 8  # as `racer models ls` shows them
    done = plot_cli(tmp_path / "store", run_id, tmp_path / "out")
    assert done.exit_code == 0, done.output
    drawn = read_png(tmp_path / "out" / "trajectories.png", TRAJECTORY_FIGSIZE)
    four = read_png(plot_trajectories(run_id, runs, tmp_path / "v4.png", version=4), TRAJECTORY_FIGSIZE)
    assert np.array_equal(drawn, four)


def test_plot_run_draws_the_checkpoint_asked_for(tmp_path, run_id):
    runs = write_run_with_checkpoints(tmp_path / "store", run_id)
    eight = read_png(plot_trajectories(run_id, runs, tmp_path / "v8.png", version=8), TRAJECTORY_FIGSIZE)
    for checkpoint in ("latest", 8):
        paths = plot_run(run_id, runs, tmp_path / str(checkpoint), checkpoint=checkpoint)
        assert np.array_equal(read_png(paths[1], TRAJECTORY_FIGSIZE), eight)
    with pytest.raises(UserError, match="checkpoint 5"):
        plot_run(run_id, runs, tmp_path / "five", checkpoint=5)


def test_a_checkpoint_is_best_latest_or_a_version_number():
    given = ("best", "latest", "LATEST", "12", "0")
    assert [checkpoint_choice(t) for t in given] == ["best", "latest", "latest", 12, 0]
    for bad in ("bets", "-1", "1.5", "", "1000000000"):
        with pytest.raises(OptionError) as info:
            checkpoint_choice(bad)
        message = str(info.value)
        assert "--checkpoint" in message and repr(bad) in message and "\n" not in message


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_racer_plot_checkpoint_picks_the_evaluation_drawn(tmp_path, run_id):
    runs = write_run_with_checkpoints(tmp_path / "store", run_id)
    four = read_png(plot_trajectories(run_id, runs, tmp_path / "v4.png", version=4), TRAJECTORY_FIGSIZE)
    eight = read_png(plot_trajectories(run_id, runs, tmp_path / "v8.png", version=8), TRAJECTORY_FIGSIZE)
    for checkpoint, expected in (("best", four), ("latest", eight), ("8", eight), ("4", four)):
        out = tmp_path / f"out-{checkpoint}"
        done = plot_cli(tmp_path / "store", run_id, out, "--checkpoint", checkpoint)
        assert done.exit_code == 0, done.output
        assert np.array_equal(read_png(out / "trajectories.png", TRAJECTORY_FIGSIZE), expected), checkpoint


@pytest.mark.parametrize("bad", ["bets", "-1", "1.5"])
def test_racer_plot_bad_checkpoint_is_a_one_line_error(tmp_path, run_id, bad):
    write_run_with_checkpoints(tmp_path / "store", run_id)
    done = plot_cli(tmp_path / "store", run_id, tmp_path / "out", "--checkpoint", bad)
    assert done.exit_code == 2
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1 and "--checkpoint" in err and repr(bad) in err, err
    assert not (tmp_path / "out").exists()  # refused before anything is drawn
