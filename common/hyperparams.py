"""DeepRacer's ``hyperparameters.json``, read and written in DeepRacer's own format.

Every key the DeepRacer simapp reads is accepted, with the simapp's default when it is missing
(``markov/sagemaker_graph_manager.py``, ``get_updated_hyper_parameters``; ``training_worker.py`` for
``max_sample_count`` and ``sampling_frequency``). Keys that change nothing in racer's clipped PPO are accepted and
reported by :meth:`Hyperparameters.ignored` (``sac_alpha``; ``term_cond_avg_score``, which the simapp reads but
never uses; ε-greedy settings with categorical exploration). racer adds four PPO knobs of its own (``clip_epsilon``,
``gae_lambda``, ``value_loss_coef``, ``max_grad_norm``; the simapp hard-codes 0.2 and 0.95 for the first two), how a
continuous policy acts greedily (``greedy_action``) and stability knobs (``STABILITY_KEYS``: target-KL early
stopping, learning-rate and entropy schedules, the collapse guard), all off by default, which is DeepRacer's
behaviour. Any other key is what the simapp does with it, ignored (it reads the keys above with ``hp_dict.get`` and
nothing else), but never silently: :meth:`Hyperparameters.ignored` lists it. A key that looks like a misspelt known
key (``learning_rate`` for ``lr``, ``batchsize``) is an error naming the key it resembles, since ignoring it would
silently train with the default.
"""

from __future__ import annotations

import difflib
import json
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, ValidationInfo, field_validator

from common.errors import OptionError, UserError
from common.jsonfile import read_json_object

# The keys DeepRacer itself writes, in the order its console writes them.
DEEPRACER_KEYS: tuple[str, ...] = (
    "batch_size",
    "beta_entropy",
    "discount_factor",
    "e_greedy_value",
    "epsilon_steps",
    "exploration_type",
    "loss_type",
    "lr",
    "num_episodes_between_training",
    "num_epochs",
    "stack_size",
    "term_cond_avg_score",
    "term_cond_max_episodes",
)
SIMAPP_ONLY_KEYS: tuple[str, ...] = ("sac_alpha", "max_sample_count", "sampling_frequency")
"""Keys the simapp reads that racer accepts and does not use (SAC's entropy weight; the simapp's sample collector)."""
STABILITY_KEYS: tuple[str, ...] = (
    "target_kl",
    "lr_schedule",
    "lr_final_fraction",
    "lr_cooldown",
    "entropy_schedule",
    "entropy_final_fraction",
    "schedule_updates",
    "collapse_guard",
    "collapse_min_best",
    "collapse_drop",
    "collapse_patience",
    "collapse_lr_factor",
    "collapse_lr_floor",
    "collapse_slowdown",
)
"""racer's stability knobs (README, "Stability knobs"): each off by default, which is DeepRacer's behaviour."""
RACER_KEYS: tuple[str, ...] = (
    "clip_epsilon",
    "gae_lambda",
    "value_loss_coef",
    "max_grad_norm",
    "greedy_action",
    *STABILITY_KEYS,
)
FLAGS: tuple[str, ...] = ("collapse_guard",)
"""The keys that take JSON true/false (every other key refuses a bool, which would pass as 1/0)."""

MISNAMED: dict[str, str] = {
    "learning_rate": "lr",
    "gamma": "discount_factor",
    "discount": "discount_factor",
    "entropy": "beta_entropy",
    "entropy_coef": "beta_entropy",
    "ent_coef": "beta_entropy",
    "epochs": "num_epochs",
    "n_epochs": "num_epochs",
    "episodes_between_training": "num_episodes_between_training",
    "clip_range": "clip_epsilon",
    "gae": "gae_lambda",
    "lambda": "gae_lambda",
}
"""Names other PPO libraries use for DeepRacer's keys: a file that has one meant the DeepRacer key."""

GreedyAction = Literal["mean", "expected"]
"""How a continuous policy acts greedily (``Hyperparameters.greedy_action``)."""

HUBER = "huber"
MEAN_SQUARED_ERROR = "mean squared error"


class HyperparametersError(UserError, ValueError):
    """A hyperparameters file that cannot be used; the one-line message names the file and the bad key."""


class Hyperparameters(BaseModel):
    """Training hyperparameters: DeepRacer's keys plus racer's PPO knobs."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=True)
    _unread: list[str] = PrivateAttr(default_factory=list)

    batch_size: int = Field(64, ge=1)
    """PPO minibatch size, steps (env transitions) per gradient step."""
    beta_entropy: float = Field(0.01, ge=0)
    """Entropy bonus coefficient, dimensionless (weight of the mean policy entropy in the loss)."""
    discount_factor: float = Field(0.999, gt=0, le=1)
    """Discount γ per env step, dimensionless."""
    e_greedy_value: float = Field(0.05, ge=0, le=1)
    """Final ε of DeepRacer's ε-greedy schedule, a probability; used only with ``exploration_type`` e-greedy."""
    epsilon_steps: int = Field(10000, ge=0)
    """Length of DeepRacer's ε schedule, env steps; used only with ``exploration_type`` e-greedy."""
    exploration_type: Literal["categorical", "additive_noise"] = "categorical"
    """Exploration: ``categorical`` (sample the policy; DeepRacer's continuous spaces add Gaussian noise under this
    name too) or ``additive_noise``. DeepRacer's ``e-greedy`` is refused: racer's PPO samples its policy."""
    loss_type: Literal["huber", "mean squared error"] = MEAN_SQUARED_ERROR
    """Value-function loss: ``huber`` or ``mean squared error`` (``mse`` is accepted and stored as the latter);
    the simapp's default is mean squared error."""
    lr: float = Field(0.0003, gt=0)
    """Adam learning rate, per gradient step."""
    num_episodes_between_training: int = Field(20, ge=1)
    """Episodes collected between two policy updates, episodes."""
    num_epochs: int = Field(10, ge=1)
    """Passes over the collected batch per policy update, epochs."""
    stack_size: int = Field(1, ge=1, le=8)
    """Consecutive camera frames stacked into one observation, frames."""
    term_cond_avg_score: float = 100000.0
    """Read and kept, never used: the simapp reads it and stops on nothing (its default is 100000)."""
    term_cond_max_episodes: int = Field(100000, ge=1)
    """Stop after this many policy updates: despite its name, the simapp's training loop counts training
    iterations against it (``training_worker.py``: ``steps += 1`` per ``graph_manager.train()``)."""
    sac_alpha: float = Field(0.2, gt=0)
    """SAC's entropy weight; accepted for DeepRacer's files, unused by racer's clipped PPO."""
    max_sample_count: int = Field(0, ge=0)
    """The simapp's sample collector (samples uploaded for debugging); accepted, unused."""
    sampling_frequency: int = Field(1, ge=1)
    """The simapp's sample collector's frequency; accepted, unused."""

    clip_epsilon: float = Field(0.2, gt=0, lt=1)
    """racer: PPO clip range ε of the probability ratio, dimensionless."""
    gae_lambda: float = Field(0.95, ge=0, le=1)
    """racer: GAE λ, dimensionless (1 = Monte-Carlo advantages, 0 = one-step TD)."""
    value_loss_coef: float = Field(0.5, ge=0)
    """racer: weight of the value loss in the total loss, dimensionless."""
    max_grad_norm: float = Field(0.5, gt=0)
    """racer: global gradient-norm clip, L2 norm of all parameter gradients."""
    greedy_action: GreedyAction = "mean"
    """racer, continuous action spaces only: the action the policy takes when it acts greedily (evaluation, ``racer
    eval``, ``racer export``). ``mean`` (DeepRacer): the Gaussian's mean, which the env clips to the action range.
    ``expected``: the mean of the action the env executes, that is of the Gaussian censored at the range's bounds
    (``common.policy.censored_mean``): the action a policy trained with its noise drives on average, also where its
    mean has left the range (docs/racing.md)."""

    target_kl: float | None = Field(None, gt=0)
    """racer: stop a policy update's remaining epochs once an epoch's mean approx KL(old || new) exceeds this,
    nats; None = run every epoch (DeepRacer)."""
    lr_schedule: Literal["constant", "linear"] = "constant"
    """racer: ``constant`` (DeepRacer) or ``linear``: ``lr`` decays to ``lr * lr_final_fraction`` over
    ``schedule_updates`` policy updates."""
    lr_final_fraction: float = Field(0.1, ge=0, le=1)
    """racer: the final value of the linear learning-rate schedule and of the cool-down, a fraction of ``lr``."""
    lr_cooldown: float | None = Field(None, gt=0, le=1)
    """racer: over this last share of the run's time limit (``--time-limit``), the learning rate falls linearly to
    ``lr_final_fraction`` of what it would be (0.2: the last fifth), so that a run ends on small updates, as PPO's
    own schedule anneals its rate to the end of training; None = no cool-down (DeepRacer). Needs a time limit."""
    entropy_schedule: Literal["constant", "linear"] = "constant"
    """racer: ``constant`` (DeepRacer) or ``linear``: ``beta_entropy`` decays to ``beta_entropy *
    entropy_final_fraction`` over ``schedule_updates`` policy updates."""
    entropy_final_fraction: float = Field(0.1, ge=0, le=1)
    """racer: the linear entropy schedule's final value, a fraction of ``beta_entropy``."""
    schedule_updates: int = Field(500, ge=1)
    """racer: length of the linear schedules, policy updates; the final value holds after it."""
    collapse_guard: bool = Field(False, strict=True)
    """racer: roll back to the ``best`` checkpoint (weights and optimizer) at a lower learning rate when the
    robust evaluations of newer checkpoints collapse; false = never (DeepRacer)."""
    collapse_min_best: float = Field(0.25, gt=0, le=1)
    """racer: the guard acts only once the best checkpoint completes at least this fraction of its evaluation
    trials (below it there is little to collapse from, and one lap more or less is noise)."""
    collapse_drop: float = Field(0.5, gt=0, le=1)
    """racer: an evaluation is collapsed when its completion is at most ``best completion * (1 - collapse_drop)``
    (0.5: half the best's or less; 1: none at all)."""
    collapse_patience: int = Field(2, ge=1)
    """racer: consecutive collapsed evaluations (of checkpoints newer than the best) before rolling back."""
    collapse_lr_factor: float = Field(0.5, gt=0, le=1)
    """racer: each rollback multiplies the learning rate (and what the schedule gives later) by this."""
    collapse_lr_floor: float = Field(0.1, ge=0, le=1)
    """racer: the rollbacks never take the learning rate below this fraction of the schedule's (0: no floor). Without
    one, a run that keeps rolling back to an early best halves its rate each time until learning stops."""
    collapse_slowdown: float | None = Field(None, gt=0)
    """racer: an evaluation whose mean lap is more than ``1 + collapse_slowdown`` times the best checkpoint's
    also counts as collapsed (0.15: 15 % slower), so the guard also undoes a drift to slower laps, not only lost
    completion; None = completion only."""

    @field_validator("*", mode="before")
    @classmethod
    def _no_bools(cls, value: Any, info: ValidationInfo) -> Any:
        # JSON true/false would otherwise pass as 1/0 for a number; only the FLAGS are flags.
        if isinstance(value, bool) and info.field_name not in FLAGS:
            raise ValueError("expected a number or a string, not true/false")
        return value

    @field_validator("loss_type", mode="before")
    @classmethod
    def _mse_alias(cls, value: Any) -> Any:
        # The simapp lower-cases it; "mse" is common shorthand. Store DeepRacer's spelling for to_json().
        value = value.lower().strip() if isinstance(value, str) else value
        return MEAN_SQUARED_ERROR if value == "mse" else value

    @field_validator("exploration_type", mode="before")
    @classmethod
    def _exploration(cls, value: Any) -> Any:
        value = value.lower().strip() if isinstance(value, str) else value
        if value == "e-greedy":
            raise ValueError("e-greedy exploration is not supported: racer's PPO samples its policy (use categorical)")
        return value

    def ignored(self) -> list[str]:
        """The keys given in the file that change nothing in racer's training, with why; for a one-time log."""
        given = self.model_fields_set
        notes = [f"{key} (not used by clipped PPO)" for key in ("sac_alpha",) if key in given]
        notes += [f"{key} (the simapp's sample collector)" for key in SIMAPP_ONLY_KEYS[1:] if key in given]
        if "term_cond_avg_score" in given:
            notes.append("term_cond_avg_score (DeepRacer reads it and never stops on it)")
        if self.exploration_type == "categorical":
            notes += [
                f"{key} (only for e-greedy exploration)" for key in ("e_greedy_value", "epsilon_steps") if key in given
            ]
        notes += self._idle_stability_keys(given)
        notes += [f"{key} (DeepRacer does not read it either)" for key in self._unread]
        return notes

    def _idle_stability_keys(self, given: set[str]) -> list[str]:
        """Stability knobs given in the file whose switch is off, so that they change nothing."""
        idle = []
        if self.lr_schedule == "constant" and self.lr_cooldown is None and "lr_final_fraction" in given:
            idle.append("lr_final_fraction (only with lr_schedule linear or lr_cooldown)")
        if self.entropy_schedule == "constant" and "entropy_final_fraction" in given:
            idle.append("entropy_final_fraction (only with entropy_schedule linear)")
        if self.lr_schedule == self.entropy_schedule == "constant" and "schedule_updates" in given:
            idle.append("schedule_updates (only with a linear schedule)")
        if not self.collapse_guard:
            idle += [
                f"{key} (only with collapse_guard true)"
                for key in STABILITY_KEYS
                if key.startswith("collapse_") and key != "collapse_guard" and key in given
            ]
        return idle

    @property
    def value_loss_kind(self) -> Literal["huber", "mse"]:
        """``loss_type`` as the trainer's ``value_loss`` names it."""
        return "huber" if self.loss_type == HUBER else "mse"

    def to_json(self) -> str:
        """hyperparameters.json text as DeepRacer writes it: every DeepRacer key, in DeepRacer's order.

        racer's own PPO knobs are added only where they differ from their defaults, so a default file is
        exactly DeepRacer's and a non-default one still round-trips through ``load_hyperparameters``.
        """
        data = {key: getattr(self, key) for key in DEEPRACER_KEYS}
        for key in RACER_KEYS:
            if getattr(self, key) != type(self).model_fields[key].default:
                data[key] = getattr(self, key)
        return json.dumps(data, indent=4)


def load_hyperparameters(path: str | Path) -> Hyperparameters:
    """Read a ``hyperparameters.json``; missing keys take their defaults.

    Raises HyperparametersError with a one-line message naming the file and the bad key and value.
    """
    p = Path(path)
    where = f"hyperparameters file {str(p)!r}"
    data = read_json_object(p, "hyperparameters file", HyperparametersError)
    unread = [key for key in data if key not in Hyperparameters.model_fields]
    # Every misspelt key in the one error, so a file with several is fixed in one try.
    misspelt = [f"unknown key {key!r} (did you mean {meant!r}?)" for key in unread if (meant := _resembles(key))]
    if misspelt:
        raise HyperparametersError(f"{where}: {'; '.join(misspelt)}")
    try:
        hp = Hyperparameters.model_validate({k: v for k, v in data.items() if k not in unread})
    except ValidationError as exc:
        raise HyperparametersError(f"{where}: {_describe(exc)}") from None
    hp._unread = unread
    return hp


def _resembles(key: str) -> str | None:
    """The known key an unknown one looks like a misspelling or another library's name of, if any."""
    known = list(Hyperparameters.model_fields)
    folded = key.lower().strip().replace("-", "_").replace(" ", "_")
    if folded in known and folded != key:
        return folded
    if folded in MISNAMED:
        return MISNAMED[folded]
    close = difflib.get_close_matches(folded, known, n=1, cutoff=0.8)
    return close[0] if close else None


def _describe(exc: ValidationError) -> str:
    """The validation errors on one line: ``key = value: reason; ...``."""
    parts = []
    for err in exc.errors():
        key = ".".join(str(v) for v in err["loc"]) or "file"
        if err["type"] == "extra_forbidden":
            parts.append(f"unknown key {key!r} (allowed: {', '.join(DEEPRACER_KEYS + SIMAPP_ONLY_KEYS + RACER_KEYS)})")
        else:
            parts.append(f"{key} = {json.dumps(err['input'], default=repr)}: {err['msg']}")
    return "; ".join(parts)


def check_cooldown(lr_cooldown: float | None, time_limit_s: float | None) -> None:
    """Refuse a learning-rate cool-down (``lr_cooldown``) without a time limit to count it back from."""
    if lr_cooldown is not None and time_limit_s is None:
        raise OptionError(
            f"hyperparameters.json: lr_cooldown {lr_cooldown} needs a time limit to cool down towards: "
            "give --time-limit, or remove lr_cooldown"
        )
