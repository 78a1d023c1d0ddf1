"""What racer prints for people: the training time bar, the end-of-run summary, `racer models ls` at 80 columns,
`racer --version`."""

from __future__ import annotations

import json
import time
from pathlib import Path

from rich.console import Console
from typer.testing import CliRunner

from model_store import LocalStore, RunStore
from racer.cli import app
from racer.commands.models import models_tables as _models_tables
from racer.launcher import _duration, _time_bar, run_summary


def test_time_bar_shows_the_fraction_done_and_the_time_left() -> None:
    assert _time_bar(30.0, 120.0, width=20) == "━━━━━───────────────  25 %  1m30s left"
    assert _time_bar(500.0, 120.0, width=4).startswith("━━━━ 100 %  0s left")  # past the limit: full, none left
    assert _time_bar(3725.0, None) == "1h02m trained"
    assert (_duration(59.4), _duration(61), _duration(7200)) == ("59s", "1m01s", "2h00m")


def _run_with_best(root: Path, laps: list[float] | None) -> RunStore:
    runs = RunStore(LocalStore(str(root)))
    runs.save_checkpoint("r1", 3, b"weights", {"env_steps": 4096, "created": time.time()})
    runs.set_pointer("r1", "best", 3)
    if laps is not None:
        evaluation = {"episodes": 4, "completion_rate": len(laps) / 4, "lap_times_s": laps, "mean_progress": 90.0}
        runs.write_file("r1", "evaluations/000000003.json", json.dumps(evaluation))
    return runs


def test_run_summary_names_the_best_checkpoint_its_laps_and_the_next_commands(tmp_path: Path) -> None:
    lines = run_summary("r1", _run_with_best(tmp_path, [10.0, 9.0, 11.0]), ".", None)
    assert lines[0] == f"run files: {tmp_path}/runs/r1/"
    assert lines[1] == "best checkpoint: v3, robust evaluation 75 % of 4 laps completed, mean lap 10.00 s, best 9.00 s"
    assert "  racer eval --run-id r1 --video lap.mp4" in lines
    s3 = run_summary("r1", _run_with_best(tmp_path / "other", None), "s3://b/p", "http://127.0.0.1:9000")
    assert "best checkpoint: v3 (not evaluated)" in s3
    assert "  racer models ls --store s3://b/p --s3-endpoint http://127.0.0.1:9000" in s3


def test_run_summary_of_a_run_without_checkpoints_says_to_train_longer(tmp_path: Path) -> None:
    runs = RunStore(LocalStore(str(tmp_path)))
    runs.write_file("r2", "config.json", "{}")
    assert run_summary("r2", runs, ".", None)[-1] == "no checkpoint was written: train for longer (--time-limit)"


def test_run_summary_before_any_evaluation_points_at_the_latest_checkpoint(tmp_path: Path) -> None:
    runs = RunStore(LocalStore(str(tmp_path)))
    runs.save_checkpoint("r3", 0, b"weights", {"env_steps": 0, "created": time.time()})  # v0 is never evaluated
    lines = run_summary("r3", runs, ".", None)
    assert lines[1] == "no checkpoint evaluated yet: train for longer; latest checkpoint: v0"
    assert "  racer eval --run-id r3 --checkpoint latest --video lap.mp4" in lines
    assert "  racer export --run-id r3 --checkpoint latest -o model.onnx" in lines


def _rows(n: int) -> list[dict]:
    evaluation = {"completion_rate": 1.0, "mean_progress": 100.0, "best_lap_s": 9.87}
    return [
        {
            "run_id": "run-20261125-115553",
            "version": v,
            "env_steps": 1_234_567,
            "created": 1.8e9,
            "size_bytes": 23_100_000,
            "evaluation": evaluation if v % 2 else None,
            "latest": v == n,
            "best": v == 1,
        }
        for v in range(1, n + 1)
    ]


def test_models_ls_fits_80_columns_one_line_per_checkpoint() -> None:
    console = Console(width=80, record=True, color_system=None)
    for table in _models_tables(_rows(12), wide=False):
        console.print(table)
    lines = console.export_text().splitlines()
    assert lines[0].strip() == "run-20261125-115553"
    body = [line for line in lines[2:] if line.strip()]
    assert len(body) == 12  # one line per checkpoint: nothing wrapped
    assert all(len(line) <= 80 for line in lines) and "…" not in "".join(lines)
    assert "1,234,567" in body[0] and "9.87 s" in body[0] and body[0].rstrip().endswith("best")
    assert body[-1].rstrip().endswith("latest")


def test_models_ls_wide_has_the_run_on_every_row() -> None:
    console = Console(width=160, record=True, color_system=None)
    for table in _models_tables(_rows(2), wide=True):
        console.print(table)
    text = console.export_text()
    assert text.count("run-20261125-115553") == 2


def test_version() -> None:
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0 and result.stdout.startswith("racer ")


def test_models_prune_says_what_it_frees_and_keeps_latest_and_best(tmp_path: Path) -> None:
    runs = _run_with_best(tmp_path, [9.0])  # best = v3
    for v in (4, 5, 6):
        runs.save_checkpoint("r1", v, b"w" * 1_000_000, {"env_steps": v}, optimizer=b"o" * 2_000_000)
    store = ["--store", str(tmp_path)]
    dry = CliRunner().invoke(app, ["models", "prune", *store, "--keep", "0", "--dry-run"])
    assert dry.exit_code == 0 and "r1: would free 6.0 MB (2 checkpoints, 0 optimizer states)" in dry.stdout
    done = CliRunner().invoke(app, ["models", "prune", *store, "--keep", "0", "--json", "-"])
    assert json.loads(done.stdout)[0]["checkpoints"] == [4, 5]  # their optimizer states go with them
    assert [c["version"] for c in runs.list_checkpoints("r1")] == [3, 6]
    missing = CliRunner().invoke(app, ["models", "prune", *store, "--run-id", "nope"])
    assert missing.exit_code == 2 and "run 'nope' does not exist" in missing.stderr


def test_roles_log_no_per_step_simtrace_lines_unless_asked() -> None:
    import logging

    from common.simtrace import LOG as SIMTRACE_LOG
    from racer.lifecycle import setup_logging

    setup_logging()  # what racer worker and racer evaluator do
    assert not SIMTRACE_LOG.isEnabledFor(logging.INFO)
    setup_logging(simtrace_lines=True)  # racer worker --simtrace-log
    assert SIMTRACE_LOG.isEnabledFor(logging.INFO)
    SIMTRACE_LOG.setLevel(logging.NOTSET)
