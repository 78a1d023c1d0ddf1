"""Tests of DeepRacer's hyperparameters.json (common.hyperparams)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pydantic import ValidationError

from common.hyperparams import (
    DEEPRACER_KEYS,
    RACER_KEYS,
    STABILITY_KEYS,
    Hyperparameters,
    HyperparametersError,
    load_hyperparameters,
)

# A hyperparameters.json as the DeepRacer console writes it.
DEEPRACER_FILE = {
    "batch_size": 64,
    "beta_entropy": 0.01,
    "discount_factor": 0.95,
    "e_greedy_value": 1.0,
    "epsilon_steps": 10000,
    "exploration_type": "categorical",
    "loss_type": "huber",
    "lr": 0.0003,
    "num_episodes_between_training": 20,
    "num_epochs": 3,
    "stack_size": 1,
    "term_cond_avg_score": 100000.0,
    "term_cond_max_episodes": 100000,
}


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "hyperparameters.json"
    path.write_text(text)
    return path


def test_deepracer_file_loads(tmp_path: Path) -> None:
    hp = load_hyperparameters(_write(tmp_path, json.dumps(DEEPRACER_FILE)))
    assert hp.model_dump(include=set(DEEPRACER_KEYS)) == DEEPRACER_FILE
    assert hp.value_loss_kind == "huber"
    # racer's PPO knobs take their defaults when DeepRacer's file does not name them
    assert (hp.clip_epsilon, hp.gae_lambda, hp.value_loss_coef, hp.max_grad_norm) == (0.2, 0.95, 0.5, 0.5)


def test_defaults_are_the_simapps() -> None:
    # deepracer-simapp markov/sagemaker_graph_manager.py, get_updated_hyper_parameters: the value used when the
    # key is missing (hp_dict.get(key, default)).
    hp = Hyperparameters()
    assert hp.batch_size == 64 and hp.beta_entropy == 0.01 and hp.discount_factor == 0.999
    assert hp.e_greedy_value == 0.05 and hp.epsilon_steps == 10000 and hp.exploration_type == "categorical"
    assert hp.loss_type == "mean squared error" and hp.lr == 0.0003 and hp.num_episodes_between_training == 20
    assert hp.num_epochs == 10 and hp.stack_size == 1 and hp.sac_alpha == 0.2
    assert hp.term_cond_avg_score == 100000 and hp.term_cond_max_episodes == 100000


def test_drfc_default_file_is_accepted_and_its_unused_keys_reported(tmp_path: Path) -> None:
    # deepracer-for-cloud defaults/hyperparameters.json carries sac_alpha beside the PPO keys.
    data = DEEPRACER_FILE | {"sac_alpha": 0.2, "term_cond_avg_score": 350.0, "e_greedy_value": 0.05}
    hp = load_hyperparameters(_write(tmp_path, json.dumps(data)))
    notes = " ".join(hp.ignored())
    assert "sac_alpha" in notes and "term_cond_avg_score" in notes and "e_greedy_value" in notes
    assert "lr" not in notes


def test_e_greedy_exploration_is_refused_in_one_line(tmp_path: Path) -> None:
    path = _write(tmp_path, json.dumps({"exploration_type": "E-Greedy"}))
    with pytest.raises(HyperparametersError, match="exploration_type.*e-greedy.*not supported") as info:
        load_hyperparameters(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_empty_object_is_all_defaults(tmp_path: Path) -> None:
    assert load_hyperparameters(_write(tmp_path, "{}")) == Hyperparameters()


@pytest.mark.parametrize("spelling", ["mean squared error", "mse"])
def test_mse_spellings(tmp_path: Path, spelling: str) -> None:
    hp = load_hyperparameters(_write(tmp_path, json.dumps({"loss_type": spelling})))
    assert hp.loss_type == "mean squared error"  # stored as DeepRacer writes it
    assert hp.value_loss_kind == "mse"


def test_racer_knobs_allowed(tmp_path: Path) -> None:
    text = json.dumps(DEEPRACER_FILE | {"clip_epsilon": 0.1, "gae_lambda": 0.9, "value_loss_coef": 1.0})
    hp = load_hyperparameters(_write(tmp_path, text))
    assert (hp.clip_epsilon, hp.gae_lambda, hp.value_loss_coef) == (0.1, 0.9, 1.0)


def test_greedy_action_defaults_to_the_mean_and_round_trips(tmp_path: Path) -> None:
    assert Hyperparameters().greedy_action == "mean"
    assert "greedy_action" not in json.loads(Hyperparameters().to_json())
    hp = load_hyperparameters(_write(tmp_path, json.dumps(DEEPRACER_FILE | {"greedy_action": "expected"})))
    assert hp.greedy_action == "expected" and json.loads(hp.to_json())["greedy_action"] == "expected"
    assert load_hyperparameters(_write(tmp_path, hp.to_json())) == hp


def test_to_json_is_deepracer_format(tmp_path: Path) -> None:
    hp = Hyperparameters.model_validate(DEEPRACER_FILE)
    data = json.loads(hp.to_json())
    assert list(data) == list(DEEPRACER_KEYS)  # every DeepRacer key, no racer key at its default
    assert data == DEEPRACER_FILE
    assert load_hyperparameters(_write(tmp_path, hp.to_json())) == hp


def test_to_json_keeps_non_default_racer_knobs(tmp_path: Path) -> None:
    hp = Hyperparameters(loss_type="mse", gae_lambda=0.9)
    data = json.loads(hp.to_json())
    assert data["loss_type"] == "mean squared error" and data["gae_lambda"] == 0.9
    assert "clip_epsilon" not in data
    assert load_hyperparameters(_write(tmp_path, hp.to_json())) == hp


def _error(tmp_path: Path, text: str) -> str:
    path = _write(tmp_path, text)
    with pytest.raises(HyperparametersError) as info:
        load_hyperparameters(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(HyperparametersError, match="does not exist"):
        load_hyperparameters(tmp_path / "nope.json")


def test_bad_json(tmp_path: Path) -> None:
    assert "not valid JSON" in _error(tmp_path, '{"lr": 0.001,')


def test_not_an_object(tmp_path: Path) -> None:
    assert "expected a JSON object" in _error(tmp_path, "[1, 2]")


def test_unknown_key_is_a_typo(tmp_path: Path) -> None:
    message = _error(tmp_path, json.dumps(DEEPRACER_FILE | {"learning_rate": 0.001}))
    assert "unknown key 'learning_rate'" in message


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("lr", 0),
        ("lr", -0.001),
        ("lr", "fast"),
        ("discount_factor", 0.0),
        ("discount_factor", 1.5),
        ("batch_size", 0),
        ("batch_size", 64.5),
        ("batch_size", True),
        ("num_epochs", 0),
        ("stack_size", 0),
        ("stack_size", 9),
        ("beta_entropy", -0.1),
        ("e_greedy_value", 2.0),
        ("num_episodes_between_training", 0),
        ("term_cond_max_episodes", 0),
        ("loss_type", "l1"),
        ("exploration_type", "e-greedy"),
        ("clip_epsilon", 0.0),
        ("gae_lambda", 1.1),
        ("max_grad_norm", 0),
        ("target_kl", 0),
        ("target_kl", -0.01),
        ("target_kl", True),
        ("lr_schedule", "cosine"),
        ("lr_final_fraction", 1.5),
        ("lr_cooldown", 0),
        ("lr_cooldown", 1.5),
        ("lr_cooldown", True),
        ("entropy_schedule", "exponential"),
        ("entropy_final_fraction", -0.1),
        ("schedule_updates", 0),
        ("collapse_guard", 1),
        ("collapse_guard", "yes"),
        ("collapse_min_best", 0),
        ("collapse_drop", 0),
        ("collapse_drop", 1.5),
        ("collapse_patience", 0),
        ("collapse_lr_factor", 0),
        ("collapse_lr_factor", 2),
        ("collapse_lr_floor", -0.1),
        ("collapse_lr_floor", 1.5),
        ("collapse_slowdown", 0),
        ("collapse_slowdown", "fast"),
        ("greedy_action", "median"),
        ("greedy_action", 1),
    ],
)
def test_bad_value_names_key_and_value(tmp_path: Path, key: str, value: object) -> None:
    message = _error(tmp_path, json.dumps(DEEPRACER_FILE | {key: value}))
    assert f"{key} = {json.dumps(value)}" in message


def test_nan_rejected(tmp_path: Path) -> None:
    assert "term_cond_avg_score = NaN" in _error(tmp_path, '{"term_cond_avg_score": NaN}')


def test_assignment_is_validated() -> None:
    hp = Hyperparameters()
    with pytest.raises(ValidationError):
        hp.lr = -1.0


def test_keys_deepracer_does_not_read_are_accepted_and_listed(tmp_path: Path) -> None:
    # The simapp reads its keys with hp_dict.get and ignores the rest (mattcamp/deepracer-local has "pretrained").
    hp = load_hyperparameters(_write(tmp_path, json.dumps(DEEPRACER_FILE | {"pretrained": "false", "notes": "v2"})))
    assert hp.lr == DEEPRACER_FILE["lr"]
    listed = " ".join(hp.ignored())
    assert "pretrained (DeepRacer does not read it either)" in listed and "notes" in listed


@pytest.mark.parametrize(
    ("key", "meant"),
    [("learning_rate", "lr"), ("batchsize", "batch_size"), ("Batch_Size", "batch_size"), ("num_epoch", "num_epochs")],
)
def test_a_key_that_looks_misspelt_is_refused_naming_the_key_it_resembles(tmp_path: Path, key, meant) -> None:
    message = _error(tmp_path, json.dumps(DEEPRACER_FILE | {key: 1}))
    assert f"unknown key {key!r} (did you mean {meant!r}?)" in message


def test_every_misspelt_key_is_named_in_the_one_error(tmp_path: Path) -> None:
    message = _error(tmp_path, json.dumps(DEEPRACER_FILE | {"learning_rate": 1e-4, "batchsize": 32}))
    assert "'learning_rate' (did you mean 'lr'?)" in message and "'batchsize' (did you mean 'batch_size'?)" in message
    assert "\n" not in message


# --- racer's stability knobs ---------------------------------------------------------------------------

STABILITY_FILE = {
    "target_kl": 0.02,
    "lr_schedule": "linear",
    "lr_final_fraction": 0.2,
    "lr_cooldown": 0.2,
    "entropy_schedule": "linear",
    "entropy_final_fraction": 0.0,
    "schedule_updates": 300,
    "collapse_guard": True,
    "collapse_min_best": 0.5,
    "collapse_drop": 0.4,
    "collapse_patience": 3,
    "collapse_lr_factor": 0.25,
    "collapse_lr_floor": 0.05,
    "collapse_slowdown": 0.2,
}


def test_stability_knobs_are_off_by_default_which_is_deepracer(tmp_path: Path) -> None:
    hp = load_hyperparameters(_write(tmp_path, json.dumps(DEEPRACER_FILE)))
    assert hp.target_kl is None  # every epoch runs
    assert hp.lr_schedule == "constant" and hp.entropy_schedule == "constant"  # lr and beta_entropy as given
    assert hp.collapse_guard is False
    assert set(STABILITY_KEYS) <= set(RACER_KEYS)
    assert not set(STABILITY_KEYS) & set(json.loads(hp.to_json()))  # a default file stays DeepRacer's


def test_stability_knobs_load_and_round_trip(tmp_path: Path) -> None:
    hp = load_hyperparameters(_write(tmp_path, json.dumps(DEEPRACER_FILE | STABILITY_FILE)))
    assert hp.model_dump(include=set(STABILITY_KEYS)) == STABILITY_FILE
    assert not [note for note in hp.ignored() if note.split()[0] in STABILITY_KEYS]  # every switch is on
    data = json.loads(hp.to_json())
    assert {k: data[k] for k in STABILITY_KEYS} == STABILITY_FILE  # every one differs from its default
    assert load_hyperparameters(_write(tmp_path, hp.to_json())) == hp


def test_collapse_guard_takes_true_and_false_where_numbers_refuse_them(tmp_path: Path) -> None:
    assert load_hyperparameters(_write(tmp_path, '{"collapse_guard": true}')).collapse_guard is True
    assert load_hyperparameters(_write(tmp_path, '{"collapse_guard": false}')).collapse_guard is False
    assert "collapse_drop = true" in _error(tmp_path, '{"collapse_guard": true, "collapse_drop": true}')


def test_knobs_whose_switch_is_off_are_listed_as_unused(tmp_path: Path) -> None:
    data = {"lr_final_fraction": 0.2, "schedule_updates": 50, "collapse_drop": 0.3, "collapse_lr_factor": 0.1}
    listed = " ".join(load_hyperparameters(_write(tmp_path, json.dumps(data))).ignored())
    assert "lr_final_fraction (only with lr_schedule linear or lr_cooldown)" in listed
    assert "schedule_updates (only with a linear schedule)" in listed
    assert "collapse_drop (only with collapse_guard true)" in listed and "collapse_lr_factor" in listed
    switched_on = data | {"lr_schedule": "linear", "collapse_guard": True}
    assert load_hyperparameters(_write(tmp_path, json.dumps(switched_on))).ignored() == []
    cooled = {"lr_final_fraction": 0.2, "lr_cooldown": 0.25}  # the cool-down reads lr_final_fraction too
    assert load_hyperparameters(_write(tmp_path, json.dumps(cooled))).ignored() == []


@pytest.mark.parametrize(("key", "meant"), [("collapse_gaurd", "collapse_guard"), ("target-kl", "target_kl")])
def test_a_misspelt_stability_knob_is_refused(tmp_path: Path, key: str, meant: str) -> None:
    message = _error(tmp_path, json.dumps({key: 1}))
    assert f"unknown key {key!r} (did you mean {meant!r}?)" in message
