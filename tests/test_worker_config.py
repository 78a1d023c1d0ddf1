"""Per-worker configurations (DRfC's DR_TRAIN_MULTI_CONFIG and worker-N.env, racer's --worker-config): each worker
drives its own track, race type, direction and randomization; the trainer and the evaluator keep the run's env."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

from common.config import RunConfig, WorkerEnv
from common.race import RaceType
from racer.drfc import DrfcError, import_drfc, read_worker_settings
from racer.runconfig import build_run, parse_worker_configs
from sim.track import load_track


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def racer(*args: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "racer", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def test_a_worker_file_sets_only_what_it_names(tmp_path: Path) -> None:
    path = write(
        tmp_path / "worker-2.env",
        "DR_WORLD_NAME=racer_wide\nDR_RACE_TYPE=OBJECT_AVOIDANCE\nDR_OA_NUMBER_OF_OBSTACLES=3\n"
        "DR_TRAIN_REVERSE_DIRECTION=True\nDR_CAR_COLOR=Red\nDR_WORKERS=9\n",
    )
    settings = read_worker_settings(path)
    assert settings.track == "racer_wide"
    assert settings.race is not None and settings.race.race_type is RaceType.OBJECT_AVOIDANCE
    assert settings.race.object_avoidance.number_of_obstacles == 3
    assert settings.randomization == {"reverse_prob": 1.0}
    # DR_CAR_COLOR is per-worker in DRfC but means nothing to racer; DR_WORKERS is not read per worker at all.
    assert settings.unmapped == ["DR_CAR_COLOR", "DR_WORKERS"]
    only_track = read_worker_settings(write(tmp_path / "w.env", "DR_WORLD_NAME=racer_loop_cw\n"))
    assert (only_track.track, only_track.race, only_track.randomization) == ("racer_loop_cw", None, None)


def test_drfc_multi_config_accumulates_worker_files_as_drfc_does(tmp_path: Path) -> None:
    write(tmp_path / "run.env", "DR_WORLD_NAME=racer_loop\nDR_WORKERS=3\nDR_TRAIN_MULTI_CONFIG=True\n")
    write(tmp_path / "worker-2.env", "DR_WORLD_NAME=racer_wide\nDR_TRAIN_ALTERNATE_DRIVING_DIRECTION=True\n")
    write(tmp_path / "worker-3.env", "DR_RACE_TYPE=TIME_TRIAL\n")
    drfc = import_drfc(tmp_path)
    assert drfc.track == "racer_loop" and drfc.workers == 3 and drfc.multi_config
    first, second, third = drfc.worker_settings
    assert first is None  # DRfC's worker 1 drives run.env
    assert second.track == "racer_wide" and second.randomization == {"alternate_direction": True}
    # prepare-config.py updates os.environ with each file in turn: worker 3 keeps worker 2's world.
    assert third.track is None and third.race is not None
    assert third.source.name == "worker-3.env"
    assert "DR_TRAIN_MULTI_CONFIG" in drfc.mapped and "DR_TRAIN_MULTI_CONFIG" not in drfc.unmapped


def test_drfc_multi_config_cumulative_world(tmp_path: Path) -> None:
    # A world set by worker-2.env holds for worker 3 unless worker-3.env names another.
    write(tmp_path / "run.env", "DR_WORKERS=3\nDR_TRAIN_MULTI_CONFIG=True\n")
    write(tmp_path / "worker-2.env", "DR_WORLD_NAME=racer_wide\n")
    write(tmp_path / "worker-3.env", "DR_TRAIN_REVERSE_DIRECTION=True\n")
    _, _, third = import_drfc(tmp_path).worker_settings
    run, _ = build_run("mc", worker_settings=import_drfc(tmp_path).worker_settings)
    assert third.randomization == {"reverse_prob": 1.0}
    assert run.worker_env(2).randomization.reverse_prob == 1.0
    assert run.worker_env(1).track == "racer_wide" and run.worker_env(0).track == run.env.track


def test_a_missing_worker_file_is_one_line_naming_it(tmp_path: Path) -> None:
    write(tmp_path / "run.env", "DR_WORKERS=3\nDR_TRAIN_MULTI_CONFIG=True\n")
    write(tmp_path / "worker-2.env", "DR_WORLD_NAME=racer_wide\n")
    with pytest.raises(DrfcError, match="worker-3.env is missing") as info:
        import_drfc(tmp_path)
    assert "\n" not in str(info.value)


def test_reverse_with_alternation_is_refused_naming_the_file(tmp_path: Path) -> None:
    path = write(
        tmp_path / "worker-2.env", "DR_TRAIN_REVERSE_DIRECTION=True\nDR_TRAIN_ALTERNATE_DRIVING_DIRECTION=True\n"
    )
    with pytest.raises(DrfcError, match="worker-2.env.*DR_TRAIN_REVERSE_DIRECTION='True'"):
        read_worker_settings(path)


def test_run_config_gives_each_worker_its_world_and_reads_old_worker_tracks() -> None:
    run = RunConfig(run_id="r", worker_envs=[WorkerEnv(), WorkerEnv(track="racer_wide")])
    assert [run.worker_env(k).track for k in range(4)] == [run.env.track, "racer_wide"] * 2
    old = RunConfig.model_validate({"run_id": "r", "worker_tracks": ["racer_loop", "racer_wide"]})
    assert [w.track for w in old.worker_envs] == ["racer_loop", "racer_wide"]
    assert RunConfig.model_validate_json(old.model_dump_json()) == old


def test_yaml_list_and_numbered_files(tmp_path: Path) -> None:
    listing = write(
        tmp_path / "workers.yaml",
        "- null\n- track: racer_wide\n  randomization: {reverse_prob: 1.0}\n  race: {race_type: OBJECT_AVOIDANCE}\n",
    )
    settings = parse_worker_configs([str(listing)], 2)
    run, _ = build_run("y", worker_settings=settings)
    second = run.worker_env(1)
    assert second.track == "racer_wide" and second.randomization.reverse_prob == 1.0
    assert second.race.race_type is RaceType.OBJECT_AVOIDANCE
    assert run.worker_env(0) == run.env
    numbered = parse_worker_configs([f"2={write(tmp_path / 'w2.env', 'DR_WORLD_NAME=racer_wide')}"], 3)
    assert numbered[0] is None and numbered[1].track == "racer_wide" and numbered[2] is None


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize(
    ("value", "text", "fragment"),
    [
        ("3=w.env", "DR_WORLD_NAME=racer_wide\n", "worker 3 is not one of 1..2"),
        ("2=missing.env", None, "'missing.env' is not a file"),
        ("two=w.env", "DR_WORLD_NAME=racer_wide\n", "expected N=FILE"),
        ("2=w.env", "DR_WORLD_NAME=no_such_track\n", "DR_WORLD_NAME='no_such_track'"),
        ("w.yaml", "- {track: racer_wide, speed: 3}\n", "entry 1: unknown key 'speed'"),
        ("w.yaml", "track: racer_wide\n", "expected a list"),
        ("w.yaml", "- {randomization: {reverse_prob: 2}}\n", "reverse_prob"),
    ],
)
def test_bad_worker_configs_are_one_line_errors(tmp_path: Path, value: str, text: str | None, fragment: str) -> None:
    name = value.split("=")[-1]
    if text is not None:
        write(tmp_path / name, text)
    proc = racer("train", "--workers", "2", "--worker-config", value, "--time-limit", "1s", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert fragment in proc.stderr and proc.stderr.strip().count("\n") == 0, proc.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").rglob("*.pt"))


def track_lengths(run_dir: Path) -> dict[str, set[float]]:
    """Each worker folder's sim-trace track_len values."""
    out: dict[str, set[float]] = {}
    for path in run_dir.glob("*/training-simtrace/*-iteration.csv"):
        with path.open() as f:
            out.setdefault(path.parent.parent.name, set()).update(
                round(float(r["track_len"]), 2) for r in csv.DictReader(f)
            )
    return out


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize("form", ["worker-config", "from-drfc"])
def test_train_drives_each_workers_own_track(tmp_path: Path, form: str) -> None:
    write(tmp_path / "worker-2.env", "DR_WORLD_NAME=racer_wide\n")
    if form == "worker-config":
        args = ["--track", "racer_loop", "--workers", "2", "--worker-config", "2=worker-2.env"]
    else:
        write(tmp_path / "run.env", "DR_WORLD_NAME=racer_loop\nDR_WORKERS=2\nDR_TRAIN_MULTI_CONFIG=True\n")
        args = ["--from-drfc", "."]
    hp = write(tmp_path / "hp.json", '{"batch_size": 32, "num_episodes_between_training": 2, "num_epochs": 1}')
    proc = racer(
        "train", *args, "--hyperparams", str(hp), "--run-id", "mc", "--no-eval", "--time-limit", "40s",
        cwd=tmp_path, timeout=240,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    lengths = track_lengths(tmp_path / "runs" / "mc")
    loop, wide = round(load_track("racer_loop").length, 2), round(load_track("racer_wide").length, 2)
    assert loop != wide
    assert lengths.get("0") == {loop} and lengths.get("1") == {wide}, lengths
    # The trainer and the evaluator keep the run's own env.
    config = RunConfig.model_validate_json((tmp_path / "runs" / "mc" / "config.json").read_text())
    assert config.env.track == "racer_loop" and config.worker_env(1).track == "racer_wide"


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_racer_check_reads_each_workers_file(tmp_path: Path) -> None:
    write(tmp_path / "run.env", "DR_WORKERS=2\nDR_TRAIN_MULTI_CONFIG=True\n")
    write(tmp_path / "worker-2.env", "DR_WORLD_NAME=racer_wide\nDR_CAR_COLOR=Red\n")
    proc = racer("check", "--from-drfc", ".", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "worker 2: track racer_wide" in proc.stdout
    assert "worker-2.env: no racer meaning, not used: DR_CAR_COLOR" in proc.stdout
    write(tmp_path / "worker-2.env", "DR_WORLD_NAME=nowhere\n")
    bad = racer("check", "--from-drfc", ".", cwd=tmp_path)
    assert bad.returncode == 2 and "worker-2.env" in bad.stderr and "'nowhere'" in bad.stderr, bad.stderr
