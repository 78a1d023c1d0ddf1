"""DeepRacer's race types and their settings: time trial, object avoidance, head-to-bot (pydantic).

The names and defaults are those of DeepRacer's simulation application, aws-deepracer-community/deepracer-simapp,
``bundle/markov/…`` (where it reads a key with ``WorldConfig.get_param(KEY, default)`` from the training or
evaluation yaml), and of deepracer-for-cloud (DRfC), which writes that yaml from its ``DR_*`` variables
(``scripts/training/prepare-config.py``, ``scripts/evaluation/prepare-config.py``; defaults in
``defaults/template-run.env``). Where the two defaults differ, the field takes the simapp's unless the docstring says
otherwise; ``docs/object-avoidance.md`` has the full notes.

============================================  ==============================  ======================================
racer field                                   simapp yaml key (default)       DRfC variable (template-run.env)
============================================  ==============================  ======================================
``RaceConfig.race_type``                      RACE_TYPE (TIME_TRIAL)          DR_RACE_TYPE (TIME_TRIAL)
``ObjectAvoidanceConfig.number_of_obstacles``  NUMBER_OF_OBSTACLES (0)         DR_OA_NUMBER_OF_OBSTACLES (6)
``ObjectAvoidanceConfig.min_distance_between_obstacles``
                                              MIN_DISTANCE_BETWEEN_OBSTACLES  DR_OA_MIN_DISTANCE_BETWEEN_OBSTACLES
                                              (2.0, % of the lap)             (2.0)
``ObjectAvoidanceConfig.randomize_obstacle_locations``
                                              RANDOMIZE_OBSTACLE_LOCATIONS    DR_OA_RANDOMIZE_OBSTACLE_LOCATIONS
                                              (False)                         (False)
``ObjectAvoidanceConfig.is_obstacle_bot_car``  IS_OBSTACLE_BOT_CAR (False)     DR_OA_IS_OBSTACLE_BOT_CAR (False)
``ObjectAvoidanceConfig.obstacle_type``        OBSTACLE_TYPE (box_obstacle)    DR_OA_OBSTACLE_TYPE (box_obstacle)
``ObjectAvoidanceConfig.object_positions``     OBJECT_POSITIONS ([])           DR_OA_OBJECT_POSITIONS (empty)
``HeadToBotConfig.number_of_bot_cars``         NUMBER_OF_BOT_CARS (0)          DR_H2B_NUMBER_OF_BOT_CARS (3)
``HeadToBotConfig.bot_car_speed``              BOT_CAR_SPEED (0.2 m/s)         DR_H2B_BOT_CAR_SPEED (0.2)
``HeadToBotConfig.min_distance_between_bot_cars``
                                              MIN_DISTANCE_BETWEEN_BOT_CARS   DR_H2B_MIN_DISTANCE_BETWEEN_BOT_CARS
                                              (2.0 m)                         (2.0)
``HeadToBotConfig.randomize_bot_car_locations``
                                              RANDOMIZE_BOT_CAR_LOCATIONS     DR_H2B_RANDOMIZE_BOT_CAR_LOCATIONS
                                              (False)                         (False)
``HeadToBotConfig.is_lane_change``             IS_LANE_CHANGE (False)          DR_H2B_IS_LANE_CHANGE (False)
``HeadToBotConfig.lower_lane_change_time``     LOWER_LANE_CHANGE_TIME (3.0 s)  DR_H2B_LOWER_LANE_CHANGE_TIME (3.0)
``HeadToBotConfig.upper_lane_change_time``     UPPER_LANE_CHANGE_TIME (5.0 s)  DR_H2B_UPPER_LANE_CHANGE_TIME (5.0)
``HeadToBotConfig.lane_change_distance``       LANE_CHANGE_DISTANCE (1.0 m)    DR_H2B_LANE_CHANGE_DISTANCE (1.0)
``HeadToBotConfig.penalty_seconds``            PENALTY_SECONDS (2.0 s)         DR_H2B_BOT_CAR_PENALTY (5.0)
``PenaltyConfig.off_track_penalty``            OFF_TRACK_PENALTY (eval 2.0 s)  DR_EVAL_OFF_TRACK_PENALTY (5.0)
``PenaltyConfig.collision_penalty``            COLLISION_PENALTY (eval 5.0 s)  DR_COLLISION_PENALTY (unset → 5.0)
``PenaltyConfig.reverse_penalty``              (config key only; unset)        –
``PenaltyConfig.immobilized_penalty``          (config key only; unset → 0)    –
``PenaltyConfig.number_of_resets``             NUMBER_OF_RESETS (0)            DR_EVAL_MAX_RESETS (100)
``PenaltyConfig.reset_behind_dist``            RESET_BEHIND_DIST (1.0 m)       DR_EVAL_RESET_BEHIND_DIST (1.0)
``PenaltyConfig.enable_mercy_reset``           ENABLE_MERCY_RESET (False)      –
``PenaltyConfig.reset_ahead_dist``             RESET_AHEAD_DIST (1.0 m)        –
``PenaltyConfig.max_resets_after_crash``       MAX_RESETS_AFTER_CRASH (3)      –
============================================  ==============================  ======================================

DRfC's template names ``DR_EVAL_COLLISION_PENALTY=5.0``, but its ``scripts/evaluation/prepare-config.py`` reads
``DR_COLLISION_PENALTY`` (default '5.0'), so DR_EVAL_COLLISION_PENALTY has no effect there;
:func:`race_config_from_drfc` reads what DRfC reads.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import IntEnum, StrEnum
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator


class RaceType(StrEnum):
    """simapp ``markov/reset/constants.py: RaceType`` (HEAD_TO_MODEL and F1 exist there too; racer has no use for
    them). In the simapp the race type itself only picks the video overlay: obstacles and bot cars appear when
    NUMBER_OF_OBSTACLES / NUMBER_OF_BOT_CARS are set, which DRfC writes only for its race type."""

    TIME_TRIAL = "TIME_TRIAL"
    OBJECT_AVOIDANCE = "OBJECT_AVOIDANCE"
    HEAD_TO_BOT = "HEAD_TO_BOT"


class ObstacleLane(IntEnum):
    """The lane of a fixed obstacle, as ``OBJECT_POSITIONS`` spells it (simapp
    ``markov/agent_ctrl/obstacles_agent_ctrl.py: ObstaclesCtrl._compute_obstacle_poses``: "Inner lane is 1, outer
    lane is -1"; the simapp takes any value other than -1 as the inner lane, racer accepts only 1 and -1).

    The inner lane is the line halfway between the centre line and the border inside the loop, in either
    direction of travel."""

    INNER = 1
    OUTER = -1


ObstacleType = Literal["box_obstacle", "deepracer_box_obstacle", "amazon_box_obstacle"]
"""simapp ``markov/agent_ctrl/constants.py: OBSTACLE_TYPE_LIST`` (the model folders under ``bundle/models``)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class ObstaclePosition(_Strict):
    """One fixed obstacle: an item of ``OBJECT_POSITIONS`` (DRfC: ``"0.23,-1"``)."""

    progress: float = Field(ge=0.0, le=1.0)
    """Where along the lap, as a FRACTION 0..1 of the centre line's length, measured from the start line in the
    direction of travel (the simapp multiplies it by the centre line's length; DRfC's docs: "progress (fraction
    [0..1])"). Not a percentage: 0.23 is 23 %."""
    lane: ObstacleLane
    """1 (or "inner") = inner lane, -1 (or "outer") = outer lane."""

    @field_validator("progress", mode="before")
    @classmethod
    def _fraction(cls, value: object) -> object:
        # The DeepRacer console shows the location in percent; catch a percentage given where a fraction is meant.
        if isinstance(value, int | float) and not isinstance(value, bool) and 1.0 < value <= 100.0:
            raise ValueError(
                f"progress is a fraction of the lap in [0, 1] (DeepRacer's OBJECT_POSITIONS), got {value}; "
                f"for {value} % write {value / 100:g}"
            )
        return value

    @field_validator("lane", mode="before")
    @classmethod
    def _lane_name(cls, value: object) -> object:
        if isinstance(value, str):
            names = {"inner": 1, "inside": 1, "outer": -1, "outside": -1, "1": 1, "-1": -1}
            key = value.strip().lower()
            if key not in names:
                raise ValueError(f"lane must be 1 / 'inner' or -1 / 'outer', got {value!r}")
            return names[key]
        return value


def parse_object_positions(text: str) -> list[ObstaclePosition]:
    """DRfC's ``DR_OA_OBJECT_POSITIONS`` ("0.23,-1;0.46,1": ``progress,lane`` pairs separated by ";") → positions.

    DRfC splits on ";" (``scripts/training/prepare-config.py``) and the simapp splits each item on ","
    (``ObstaclesCtrl._compute_obstacle_poses``). An empty string gives an empty list."""
    if not text.strip():
        return []
    positions = []
    for item in text.split(";"):
        parts = item.split(",")
        if len(parts) != 2:
            raise ValueError(f"object position {item!r} is not 'progress,lane' (e.g. '0.23,-1')")
        try:
            progress = float(parts[0])
        except ValueError:
            raise ValueError(f"object position {item!r}: progress {parts[0]!r} is not a number") from None
        positions.append(ObstaclePosition(progress=progress, lane=parts[1]))
    return positions


class ObjectAvoidanceConfig(_Strict):
    """Static obstacles (simapp ``markov/agent_ctrl/obstacles_agent_ctrl.py: ObstaclesCtrl``)."""

    number_of_obstacles: int = Field(6, ge=0)
    """NUMBER_OF_OBSTACLES. Default 6 = DRfC's template (the simapp's own default, 0, means no obstacles).
    Ignored when ``object_positions`` is given: then there is one obstacle per position (see ``count``)."""
    min_distance_between_obstacles: float = Field(2.0, ge=0.0)
    """MIN_DISTANCE_BETWEEN_OBSTACLES, in PERCENT of the centre line's length, as the simapp's code uses it
    ("converting percent to absolute"; DRfC's docs say metres). Only for generated positions (evenly spaced or
    randomized), where it is also where the first obstacle starts."""
    randomize_obstacle_locations: bool = False
    """RANDOMIZE_OBSTACLE_LOCATIONS: new random positions and lanes every episode; False = evenly spaced, lanes
    alternating inner, outer, … Ignored when ``object_positions`` is given."""
    is_obstacle_bot_car: bool = False
    """IS_OBSTACLE_BOT_CAR: the obstacles are parked bot cars instead of boxes (overrides ``obstacle_type``)."""
    obstacle_type: ObstacleType = "box_obstacle"
    """OBSTACLE_TYPE: which box model (they differ in size and look, not in the crash rule)."""
    object_positions: list[ObstaclePosition] = Field(default_factory=list)
    """OBJECT_POSITIONS: fixed obstacles; when given they replace ``number_of_obstacles`` and the randomization."""

    @property
    def count(self) -> int:
        """How many obstacles the simapp places: one per fixed position if any, else ``number_of_obstacles``."""
        return len(self.object_positions) if self.object_positions else self.number_of_obstacles


class HeadToBotConfig(_Strict):
    """Bot cars driving their lanes (simapp ``markov/agent_ctrl/bot_cars_agent_ctrl.py: BotCarsCtrl``)."""

    number_of_bot_cars: int = Field(3, ge=0)
    """NUMBER_OF_BOT_CARS. Default 3 = DRfC's template (the simapp's own default, 0, means no bot cars)."""
    bot_car_speed: float = Field(0.2, gt=0.0)
    """BOT_CAR_SPEED, m/s: how fast the bots advance along the CENTRE line (their lane is longer or shorter).
    Must be > 0 (the simapp divides the lane-change distance by it)."""
    min_distance_between_bot_cars: float = Field(2.0, ge=0.0)
    """MIN_DISTANCE_BETWEEN_BOT_CARS, metres along the centre line (unlike the obstacles' percent); also where the
    first bot starts."""
    randomize_bot_car_locations: bool = False
    """RANDOMIZE_BOT_CAR_LOCATIONS: random start positions and lanes every episode; False = evenly spaced, lanes
    alternating inner, outer, …"""
    is_lane_change: bool = False
    """IS_LANE_CHANGE: bots switch lanes now and then."""
    lower_lane_change_time: float = Field(3.0, ge=0.0)
    """LOWER_LANE_CHANGE_TIME, s: the shortest wait before a bot starts its next lane change."""
    upper_lane_change_time: float = Field(5.0, ge=0.0)
    """UPPER_LANE_CHANGE_TIME, s: the longest wait (the wait is uniform between the two)."""
    lane_change_distance: float = Field(1.0, gt=0.0)
    """LANE_CHANGE_DISTANCE, metres along the centre line over which a lane change happens."""
    penalty_seconds: float = Field(2.0, ge=0.0)
    """PENALTY_SECONDS as ``BotCarsCtrl`` reads it (default 2.0): how long the bots stop when one of them runs into
    the car from behind. DRfC writes DR_H2B_BOT_CAR_PENALTY (template 5.0) into it."""

    @model_validator(mode="after")
    def _times_ordered(self) -> HeadToBotConfig:
        if self.lower_lane_change_time > self.upper_lane_change_time:
            raise ValueError(
                f"lower_lane_change_time ({self.lower_lane_change_time} s) is above upper_lane_change_time "
                f"({self.upper_lane_change_time} s)"
            )
        return self


MIN_RESET_COUNT = 2
"""simapp ``markov/evaluation_worker.py: MIN_RESET_COUNT``: an evaluation allows 0 resets or at least 2."""


class PenaltyConfig(_Strict):
    """Evaluation resets: after an off-track, crash, reversal or immobilization the car is paused for a penalty
    and put back on the track, up to ``number_of_resets`` times (simapp ``markov/agent_ctrl/rollout_agent_ctrl.py:
    RolloutCtrl._check_for_phase_change``, ``_judge_action_at_run_phase``, ``_get_car_reset_model_state``). The
    defaults are the simapp's evaluation worker's (``markov/evaluation_worker.py``); training passes 0 for the
    penalties and resets (``markov/rollout_worker.py``), so any of these ends a training episode."""

    off_track_penalty: float = Field(2.0, ge=0.0)
    """OFF_TRACK_PENALTY, seconds paused after going off track (DRfC: DR_EVAL_OFF_TRACK_PENALTY, 5.0)."""
    collision_penalty: float = Field(5.0, ge=0.0)
    """COLLISION_PENALTY, seconds paused after a crash (DRfC reads DR_COLLISION_PENALTY, default 5.0)."""
    reverse_penalty: float | None = Field(None, ge=0.0)
    """Seconds paused after driving the wrong way; None = ``off_track_penalty`` (the simapp's fallback; no worker
    sets this key)."""
    immobilized_penalty: float = Field(0.0, ge=0.0)
    """Seconds paused after being immobilized (no worker sets this key, so 0)."""
    number_of_resets: int = Field(0, ge=0)
    """NUMBER_OF_RESETS: how many times an episode continues after such an event; 0 = the first one ends it
    (DRfC: DR_EVAL_MAX_RESETS, 100). The evaluation worker refuses 1."""
    reset_behind_dist: float = Field(1.0, ge=0.0)
    """RESET_BEHIND_DIST, metres along the centre line: a car reset near a static obstacle is put this far behind
    it, in the other lane (DRfC: DR_EVAL_RESET_BEHIND_DIST, 1.0)."""
    enable_mercy_reset: bool = False
    """ENABLE_MERCY_RESET: after ``max_resets_after_crash`` resets at the same obstacle, reset ahead of it."""
    reset_ahead_dist: float = Field(1.0, ge=0.0)
    """RESET_AHEAD_DIST, metres: where a mercy reset puts the car, past the obstacle."""
    max_resets_after_crash: int = Field(3, ge=1)
    """MAX_RESETS_AFTER_CRASH: resets at one obstacle before a mercy reset."""

    @field_validator("enable_mercy_reset")
    @classmethod
    def _no_mercy(cls, value: bool) -> bool:
        # Accepting it and resetting behind the obstacle every time would be a silent difference from DeepRacer.
        if value:
            raise ValueError("enable_mercy_reset is not built in racer (the car is always reset behind the obstacle)")
        return value

    @field_validator("number_of_resets")
    @classmethod
    def _resets(cls, value: int) -> int:
        if value == 1:
            raise ValueError(
                f"number_of_resets must be 0 or at least {MIN_RESET_COUNT} (DeepRacer's evaluation refuses 1)"
            )
        return value

    @property
    def reverse_penalty_s(self) -> float:
        """The penalty for driving the wrong way, with the simapp's fallback to the off-track penalty."""
        return self.off_track_penalty if self.reverse_penalty is None else self.reverse_penalty


class RaceConfig(_Strict):
    """The race: its type and the settings of its obstacles, bot cars and evaluation penalties."""

    race_type: RaceType = RaceType.TIME_TRIAL
    """RACE_TYPE."""
    object_avoidance: ObjectAvoidanceConfig = Field(default_factory=ObjectAvoidanceConfig)
    """Obstacles; used only when ``race_type`` is OBJECT_AVOIDANCE."""
    head_to_bot: HeadToBotConfig = Field(default_factory=HeadToBotConfig)
    """Bot cars; used only when ``race_type`` is HEAD_TO_BOT."""
    penalties: PenaltyConfig = Field(default_factory=PenaltyConfig)
    """Evaluation penalties and resets."""

    @property
    def obstacle_count(self) -> int:
        """Static obstacles in this race (0 unless OBJECT_AVOIDANCE)."""
        return self.object_avoidance.count if self.race_type is RaceType.OBJECT_AVOIDANCE else 0

    @property
    def bot_car_count(self) -> int:
        """Bot cars in this race (0 unless HEAD_TO_BOT)."""
        return self.head_to_bot.number_of_bot_cars if self.race_type is RaceType.HEAD_TO_BOT else 0


def _drfc_bool(env: Mapping[str, str], name: str, default: str) -> bool:
    # simapp markov/utils.py: str2bool knows 'true' and 'false' (any case); anything else stays a (truthy) string
    # there, which is surely a mistake, so racer refuses it.
    value = env.get(name, default).strip()
    if value.lower() not in ("true", "false"):
        raise ValueError(f"{name}={value!r}: expected True or False")
    return value.lower() == "true"


def race_config_from_drfc(env: Mapping[str, str], evaluation: bool = False) -> RaceConfig:
    """The race DRfC's variables describe, read as DRfC's ``scripts/{training,evaluation}/prepare-config.py`` read
    them (the same fallbacks when a variable is unset). ``evaluation`` adds the evaluation-only penalty variables;
    for training the penalties are the simapp's training values (0: no resets)."""
    race_type = RaceType(env.get("DR_RACE_TYPE", "TIME_TRIAL"))
    oa = ObjectAvoidanceConfig()
    if race_type is RaceType.OBJECT_AVOIDANCE:
        positions = parse_object_positions(env.get("DR_OA_OBJECT_POSITIONS", ""))
        oa = ObjectAvoidanceConfig(
            number_of_obstacles=int(env.get("DR_OA_NUMBER_OF_OBSTACLES", "6")),
            min_distance_between_obstacles=float(env.get("DR_OA_MIN_DISTANCE_BETWEEN_OBSTACLES", "2.0")),
            randomize_obstacle_locations=_drfc_bool(env, "DR_OA_RANDOMIZE_OBSTACLE_LOCATIONS", "True"),
            is_obstacle_bot_car=_drfc_bool(env, "DR_OA_IS_OBSTACLE_BOT_CAR", "false"),
            obstacle_type=env.get("DR_OA_OBSTACLE_TYPE", "box_obstacle"),
            object_positions=positions,
        )
    h2b = HeadToBotConfig()
    if race_type is RaceType.HEAD_TO_BOT:
        h2b = HeadToBotConfig(
            is_lane_change=_drfc_bool(env, "DR_H2B_IS_LANE_CHANGE", "False"),
            lower_lane_change_time=float(env.get("DR_H2B_LOWER_LANE_CHANGE_TIME", "3.0")),
            upper_lane_change_time=float(env.get("DR_H2B_UPPER_LANE_CHANGE_TIME", "5.0")),
            lane_change_distance=float(env.get("DR_H2B_LANE_CHANGE_DISTANCE", "1.0")),
            number_of_bot_cars=int(env.get("DR_H2B_NUMBER_OF_BOT_CARS", "0")),
            min_distance_between_bot_cars=float(env.get("DR_H2B_MIN_DISTANCE_BETWEEN_BOT_CARS", "2.0")),
            randomize_bot_car_locations=_drfc_bool(env, "DR_H2B_RANDOMIZE_BOT_CAR_LOCATIONS", "False"),
            bot_car_speed=float(env.get("DR_H2B_BOT_CAR_SPEED", "0.2")),
            penalty_seconds=float(env.get("DR_H2B_BOT_CAR_PENALTY", "2.0")),
        )
    if evaluation:
        penalties = PenaltyConfig(
            off_track_penalty=float(env.get("DR_EVAL_OFF_TRACK_PENALTY", "5.0")),
            collision_penalty=float(env.get("DR_COLLISION_PENALTY", "5.0")),
            number_of_resets=int(env.get("DR_EVAL_MAX_RESETS", "0")),
            reset_behind_dist=float(env.get("DR_EVAL_RESET_BEHIND_DIST", "1.0")),
        )
    else:
        penalties = PenaltyConfig(off_track_penalty=0.0, collision_penalty=0.0, number_of_resets=0)
    return RaceConfig(race_type=race_type, object_avoidance=oa, head_to_bot=h2b, penalties=penalties)
