"""racer bench train: the figures it derives, the SB3 side's mapping and evaluation, and one short real run."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from common.hyperparams import Hyperparameters
from model_store import LocalStore, RunStore
from racer.bench.train import (
    BenchTrainSettings,
    LapRun,
    SB3Actor,
    _lap_run,
    racer_curve,
    sb3_ppo_kwargs,
    summarize_bench,
)
from racer.runconfig import build_run
from trainer.evaluator import EvalSettings, evaluate

sb3 = pytest.importorskip("stable_baselines3", reason="racer bench train's baseline needs racer[bench]")


def _lap(system: str, seed: int, t: float | None, steps: int | None) -> LapRun:
    confirmed = None if t is None else t + 5
    return LapRun(
        system,
        seed,
        lapped=t is not None,
        time_to_lap_s=t,
        env_steps_to_lap=steps,
        wall_s=99.0,
        curve=[],
        batch_steps=800,
        first_policy_s=10.0 + seed,
        update_s=15.0 - seed,
        confirmed_s=confirmed,
    )


def test_summary_medians_bounds_and_speedup() -> None:
    settings = BenchTrainSettings(seeds=[0, 1, 2], time_limit_s=300)
    runs = [
        _lap("racer", 0, 40.0, 1600),
        _lap("sb3", 0, 90.0, 3000),
        _lap("racer", 1, 30.0, 1500),
        _lap("sb3", 1, None, None),  # did not lap: counts as the 300 s limit in the bound
        _lap("racer", 2, 50.0, 2500),
        _lap("sb3", 2, 60.0, 2000),
    ]
    out = summarize_bench(runs, settings)
    assert out["time_to_lap_s"] == 40.0 and out["env_steps_to_lap"] == 1600
    assert out["time_to_lap_spread_s"] == {"min": 30.0, "median": 40.0, "max": 50.0}
    assert out["sb3_time_to_lap_s"] == 75.0  # median of the two that lapped
    assert out["confirmed_s"] == 45.0 and out["sb3_confirmed_s"] == 80.0
    assert out["first_policy_s"] == 11.0 and out["update_s"] == 14.0  # medians over seeds 0, 1, 2
    assert out["sb3_env_steps_to_lap"] == 2500
    assert out["sb3_lapped"] == "2/3" and out["lapped"] == "3/3"
    assert out["sb3_time_to_lap_bound_s"] == 90.0  # median of 90, 300, 60
    assert out["speedup_vs_sb3"] == pytest.approx(90.0 / 40.0)
    assert out["seeds"] == [0, 1, 2] and len(out["runs"]) == 6


def test_a_run_is_judged_by_its_first_full_completion() -> None:
    curve = [
        {"time_s": 12.0, "env_steps": 900, "completion_rate": 0.5, "confirmed_s": 20.0},
        {"time_s": 21.0, "env_steps": 1800, "completion_rate": 1.0, "confirmed_s": 30.0},
        {"time_s": 33.0, "env_steps": 2700, "completion_rate": 1.0, "confirmed_s": 40.0},
    ]
    run = _lap_run("racer", 0, curve, wall_s=50.0, batch_steps=900, made_s=[12.0, 21.0, 33.0, 41.0])
    assert (run.lapped, run.time_to_lap_s, run.env_steps_to_lap, run.confirmed_s) == (True, 21.0, 1800, 30.0)
    assert run.first_policy_s == 12.0 and run.update_s == 9.0  # gaps 9, 12, 8
    never = _lap_run("sb3", 0, curve[:1], wall_s=50.0, batch_steps=900, made_s=[12.0])
    assert (never.lapped, never.time_to_lap_s, never.env_steps_to_lap, never.update_s) == (False, None, None, None)


def test_racer_curve_times_each_policy_from_its_metrics_row(tmp_path: Path) -> None:
    run = tmp_path / "runs" / "r"
    (run / "evaluations").mkdir(parents=True)
    rows = [
        {"policy_version": 1, "time": 1010.0, "env_steps": 800},
        {"policy_version": 2, "time": 1025.5, "env_steps": 1700},
    ]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    evals = {0: (0.0, 3.0, None), 1: (0.5, 60.0, 30.1), 2: (1.0, 100.0, 25.0)}
    for version, (completion, progress, best) in evals.items():
        record = {"version": version, "completion_rate": completion, "mean_progress": progress, "best_lap_s": best}
        record["created"] = 1000.0 + 20 * (version + 1)
        (run / "evaluations" / f"{version:09d}.json").write_text(json.dumps(record))
    curve = racer_curve("r", RunStore(LocalStore(tmp_path)), t0=1000.0)
    assert [p["version"] for p in curve] == [1, 2]  # version 0, the untrained policy, was never "made"
    assert [p["time_s"] for p in curve] == [10.0, 25.5]
    assert [p["confirmed_s"] for p in curve] == [40.0, 60.0]
    assert [p["env_steps"] for p in curve] == [800, 1700]
    assert curve[1]["completion_rate"] == 1.0 and curve[1]["best_lap_s"] == 25.0


def test_sb3_gets_the_runs_hyperparameters(tmp_path: Path) -> None:
    hp = Hyperparameters(lr=1e-4, batch_size=32, num_epochs=4, discount_factor=0.99, beta_entropy=0.02)
    path = tmp_path / "hp.json"
    path.write_text(hp.to_json())
    run, _ = build_run("x", hyperparams=str(path))
    kw = sb3_ppo_kwargs(run, 100, 7)
    assert (kw["learning_rate"], kw["batch_size"], kw["n_epochs"]) == (1e-4, 32, 4)
    assert (kw["gamma"], kw["ent_coef"], kw["gae_lambda"], kw["clip_range"]) == (0.99, 0.02, 0.95, 0.2)
    assert (kw["n_steps"], kw["seed"], kw["vf_coef"], kw["max_grad_norm"]) == (100, 7, 0.5, 0.5)


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_sb3_network_is_deepracers_shallow_cnn_and_is_evaluated_by_racers_code() -> None:
    from stable_baselines3 import PPO

    from sim.env import RacerEnv

    run, _ = build_run("x")
    env = RacerEnv(config=run.env)
    model = PPO("CnnPolicy", env, **sb3_ppo_kwargs(run, 16, 0))
    ours = build_policy_shapes()
    theirs = [tuple(p.shape) for p in model.policy.features_extractor.parameters()]
    assert theirs == ours, "SB3's NatureCNN should have the shapes of DeepRacer's shallow trunk"
    actor = SB3Actor(model.policy).eval()
    frame, _ = env.reset(seed=0)
    actions, _, _ = actor.act_numpy(frame[None], deterministic=True)
    expected, _ = model.predict(frame[None], deterministic=True)
    assert actions.shape == (1,) and actions[0] == expected[0]
    trials = evaluate(actor, run.env, 1, EvalSettings(episodes=1, both_directions=True))
    assert len(trials) == 2 and {t.reverse for t in trials} == {False, True}
    assert all(t.steps > 0 for t in trials)
    env.close()


def build_policy_shapes() -> list[tuple[int, ...]]:
    from common.policy import build_policy

    model = build_policy((120, 160, 1), {"kind": "discrete", "n": 10})
    return [tuple(p.shape) for p in model.trunk.parameters()]


@pytest.mark.slow(reason="runs racer train with its real processes")
def test_bench_train_short_run_writes_its_json(tmp_path: Path) -> None:
    # 20 s per system: a run that does not lap must say so and run to the limit; one that laps (SB3 can, on
    # racer_loop, from a few updates) stops at its first robust evaluation, which its curve keeps.
    out = tmp_path / "bench.json"
    cmd = [sys.executable, "-m", "racer", "bench", "train", "--seeds", "3", "--time-limit", "20s"]
    cmd += ["--sb3-n-steps", "32", "--json", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=240, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(out.read_text())
    for key in ("time_to_lap_s", "env_steps_to_lap", "sb3_time_to_lap_s", "speedup_vs_sb3", "seeds"):
        assert key in result
    assert result["seeds"] == [3]
    systems = {r["system"]: r for r in result["runs"]}
    assert set(systems) == {"racer", "sb3"}
    assert systems["sb3"]["batch_steps"] == 64  # 32 steps × 2 envs
    assert systems["sb3"]["curve"], "SB3 should have been evaluated after its updates"
    for r in result["runs"]:
        # racer's curve may be empty on a loaded machine: its first update and evaluation can take over 20 s there.
        if r["lapped"]:
            first = next(point for point in r["curve"] if point["completion_rate"] >= 1.0)
            assert r["time_to_lap_s"] == pytest.approx(first["time_s"])
            assert r["time_to_lap_s"] <= r["wall_s"] < 20 + 60
        else:
            assert r["time_to_lap_s"] is None
            assert r["wall_s"] >= 15
            assert all(point["completion_rate"] < 1.0 for point in r["curve"])
    assert result["speedup_vs_sb3"] == pytest.approx(result["sb3_time_to_lap_bound_s"] / result["time_to_lap_bound_s"])
    assert "seed 3 racer" in proc.stdout and "seed 3 sb3" in proc.stdout


@pytest.mark.slow(reason="runs racer train with its real processes")
def test_bench_train_bad_seeds_is_one_line() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "racer", "bench", "train", "--seeds", "a,b"], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "'a,b'" in proc.stderr
