"""Configuration models shared by the process roles (pydantic).

Every field carries a docstring with its unit. The environment's randomization is configured
per env, so that each rollout worker can have its own.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from common.car_calibration import CarCalibration
from common.defaults import DEFAULT_TRACK, MAX_SEGMENT_STEPS
from common.errors import OptionError, UserError
from common.hyperparams import GreedyAction, Hyperparameters
from common.race import RaceConfig

FRAME_HEIGHT, FRAME_WIDTH = 120, 160
"""The camera frame a policy sees, pixels: DeepRacer's 160×120 grayscale. The camera renders it, the network is
built for it, an exported model takes it."""

ENV_SEED_STRIDE = 1000
"""Env j of rollout worker k is seeded with the run's seed + ENV_SEED_STRIDE·k + j (``RunConfig.seed``)."""
MAX_ENVS_PER_WORKER = ENV_SEED_STRIDE
"""The most envs one worker runs (``--envs-per-worker``): more would reach the next worker's seeds."""

NetworkName = Literal["shallow", "deep", "deep_deep"]
Observation = Literal["sensors", "state"]

# DeepRacer's model_metadata "neural_network" names → racer's trunks.
_METADATA_NETWORKS: dict[str, NetworkName] = {
    "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW": "shallow",
    "DEEP_CONVOLUTIONAL_NETWORK": "deep",
    "DEEP_CONVOLUTIONAL_NETWORK_DEEP": "deep_deep",
}


class PolicyConfig(BaseModel):
    """Architecture of the actor-critic network."""

    model_config = ConfigDict(extra="forbid")

    network: NetworkName = "shallow"
    """DeepRacer's network (``common.policy.TOPOLOGIES``): ``shallow`` (DEEP_CONVOLUTIONAL_NETWORK_SHALLOW), ``deep``
    (DEEP_CONVOLUTIONAL_NETWORK) or ``deep_deep`` (DEEP_CONVOLUTIONAL_NETWORK_DEEP)."""
    dropout: float = Field(0.0, ge=0, lt=1)
    """Dropout probability before the middleware's dense layers; 0 = no Dropout module (DeepRacer's)."""
    batch_norm: bool = False
    """BatchNorm2d after each convolution."""
    l2: float = Field(0.0, ge=0)
    """L2 weight decay, used by the trainer's optimizer (not by the network), per gradient step."""
    stack_size: int = Field(1, ge=1, le=8)
    """Stacked camera frames per observation, frames: the observation's channel count."""
    greedy_action: GreedyAction = "mean"
    """How a continuous policy acts greedily: the run's ``greedy_action`` hyperparameter (``mean``: DeepRacer's)."""


def network_from_metadata(name: str) -> NetworkName:
    """racer's trunk name for DeepRacer's model_metadata ``neural_network`` value."""
    try:
        return _METADATA_NETWORKS[name]
    except KeyError:
        raise ValueError(f"unknown neural_network {name!r}; expected one of {sorted(_METADATA_NETWORKS)}") from None


PRECISIONS = ("auto", "fp32", "bf16", "fp16")
"""The trainer's PPO update arithmetic: auto (on a CPU the faster of fp32 and native bf16; on a GPU bf16, or fp16
where it has no bf16), fp32, a bf16 trunk, or an fp16 trunk with loss scaling (GPU only): ``trainer/precision.py``."""


PRECISION_HELP = (
    "The trainer's PPO update arithmetic (its trunk; weights, heads, losses and Adam stay fp32): auto (on a CPU the "
    "faster of fp32 and native bf16, timed on the first batch; on a GPU bf16 autocast, or fp16 where the GPU has no "
    "bf16), fp32, bf16 (autocast), fp16 (autocast with loss scaling; GPU only)."
)


def check_precision(precision: str) -> str:
    """``precision`` if it is one of PRECISIONS; OptionError naming it otherwise."""
    if precision not in PRECISIONS:
        raise OptionError(f"precision must be {', '.join(PRECISIONS)} (got {precision!r})")
    return precision


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class AugmentationConfig(_Strict):
    """Image augmentations of the DeepRacer paper's Table II, each applied with a probability per frame."""

    color_prob: float = Field(0.0, ge=0, le=1)
    """Probability of a random colour jitter (hue, saturation, brightness, contrast) on a frame."""
    hue_max_deg: float = Field(18.0, ge=0, le=180)
    """Largest hue shift, degrees."""
    saturation_max: float = Field(0.3, ge=0, le=1)
    """Largest relative saturation change (0.3 = ±30 %)."""
    brightness_max: float = Field(0.3, ge=0, le=1)
    """Largest relative brightness change (0.3 = ±30 %)."""
    contrast_max: float = Field(0.3, ge=0, le=1)
    """Largest relative contrast change (0.3 = ±30 %)."""
    translate_prob: float = Field(0.0, ge=0, le=1)
    """Probability of a horizontal translation of a frame."""
    translate_max_px: int = Field(10, ge=0, le=80)
    """Largest horizontal shift, pixels of the 160-pixel-wide frame."""
    shadow_prob: float = Field(0.0, ge=0, le=1)
    """Probability of a random polygonal shadow on a frame."""
    shadow_darkness: float = Field(0.5, ge=0, le=1)
    """Brightness multiplier inside a shadow is drawn from [1 - darkness, 1]."""
    salt_pepper_prob: float = Field(0.0, ge=0, le=1)
    """Probability of salt-and-pepper noise on a frame."""
    salt_pepper_amount: float = Field(0.02, ge=0, le=0.5)
    """Fraction of pixels set to black or white when the noise is applied."""
    sharpen_prob: float = Field(0.0, ge=0, le=1)
    """Probability of sharpening a frame (an unsharp mask: the frame plus a multiple of itself minus its blur)."""
    sharpen_max: float = Field(1.5, ge=0, le=5)
    """Largest sharpening amount; each sharpened frame draws its amount from [0, this]."""


class RandomizationConfig(_Strict):
    """Domain randomization of one env. All off by default except the random start position."""

    random_start: bool = True
    """Start each episode at a random waypoint; False = round-robin over the track."""
    round_robin_divisions: int = Field(20, ge=1)
    """With round-robin starts, the lap is split into this many start points (DeepRacer: 20 episodes)."""
    reverse_prob: float = Field(0.0, ge=0, le=1)
    """Probability of driving the track in the reverse direction in an episode."""
    alternate_direction: bool = False
    """DeepRacer's ``alternate_driving_direction``: episodes alternate between the two directions (first forward);
    takes the place of ``reverse_prob``."""
    action_noise: float = Field(0.0, ge=0, le=1)
    """Uniform noise on each command, as a fraction of it (0.1 = ±10 % of steering and speed)."""
    lighting: float = Field(0.0, ge=0, le=1)
    """Lighting variation per episode: overall brightness ±this fraction, plus a light gradient."""
    track_color: float = Field(0.0, ge=0, le=1)
    """Colour variation per episode of road, lines and background (0 = DeepRacer colours, 1 = any)."""
    texture: float = Field(0.0, ge=0, le=1)
    """Strength of random noise texture on road and background per episode (0 = flat colours)."""
    camera_jitter_m: float = Field(0.0, ge=0, le=0.05)
    """Camera position jitter per episode, metres (each axis)."""
    camera_jitter_deg: float = Field(0.0, ge=0, le=10)
    """Camera orientation jitter per episode, degrees (pitch, yaw, roll)."""
    friction: float = Field(0.0, ge=0, le=0.9)
    """Tyre friction scaled per episode by a factor in [1 - f, 1 + f]."""
    mass: float = Field(0.0, ge=0, le=0.9)
    """Car mass scaled per episode by a factor in [1 - m, 1 + m]."""
    augment: AugmentationConfig = Field(default_factory=AugmentationConfig)
    """Per-frame image augmentations."""


RGB = tuple[int, int, int]


class WorldCondition(_Strict):
    """A held-out condition of the world (``racer eval --condition``; ``common/conditions.py`` names them): what
    the camera sees and how the car is driven differ from training in these ways. All off by default."""

    speed_cap_mps: float | None = Field(None, gt=0, le=4.0)
    """The car's speed is capped here whatever the policy asks (the paper's 0.5 and 1 m/s on the real track), m/s."""
    road: RGB | None = None
    """Road colour, RGB 0-255 (None: the episode's)."""
    border: RGB | None = None
    """Border-line colour."""
    center: RGB | None = None
    """Centre-line colour (the road's for no centre line)."""
    background: RGB | None = None
    """What lies beside the track (the floor)."""
    sky: RGB | None = None
    """What lies beyond it, above the horizon (walls, barriers, the room)."""
    sunlight: float = Field(0.0, ge=0, le=1)
    """Strong sunlight: exposure up, a glare patch and hard-edged shadows across the frame, fixed per episode
    (1 = a bright sunny window)."""
    camera_pitch_deg: float = Field(0.0, ge=-10, le=10)
    """Added to the camera's downward tilt, degrees (a camera mounted differently)."""
    blur_px: float = Field(0.0, ge=0, le=5)
    """Gaussian blur of the frame, sigma in pixels (an out-of-focus or dirty lens, motion)."""
    sensor_noise: float = Field(0.0, ge=0, le=64)
    """Gaussian sensor noise per pixel, standard deviation in grey levels (0-255)."""
    frame_latency: int = Field(0, ge=0, le=5)
    """The policy sees the frame from this many steps ago (a slower camera pipeline), steps at 15 Hz."""


class EnvConfig(_Strict):
    """One simulated world: track, car, camera, reward, actions and randomization."""

    track: str = DEFAULT_TRACK
    """A track name (racer's own, or a DeepRacer track in the track folder) or a path to a DeepRacer .npy file."""
    reward_fn: str | None = None
    """Path to a DeepRacer reward-function .py file; None = follow the centre line (DeepRacer's example 1)."""
    action_space: str | None = None
    """Path to a DeepRacer model_metadata.json; None = DeepRacer's default 10 discrete actions."""
    camera: Literal["ground", "mujoco"] = "ground"
    """Camera path: "ground" = fast ground projection of the track texture; "mujoco" = MuJoCo's OpenGL render."""
    time_limit_steps: int = Field(3000, ge=1)
    """Time limit, steps at 15 Hz (3000 = 200 s); reaching it truncates the episode with status "time_up".
    (Not named ``max_episode_steps``: ``gymnasium.make`` takes that name for its own TimeLimit wrapper.)"""
    texture_ppm: float = Field(200.0, gt=10, le=1000)
    """Resolution of the track texture, pixels per metre (capped on large tracks)."""
    reward_time_limit_s: float | None = Field(1.0, gt=0)
    """Per-call time limit of the reward function, seconds; None = none."""
    randomization: RandomizationConfig = Field(default_factory=RandomizationConfig)
    """Domain randomization of this env."""
    car: CarCalibration = Field(default_factory=CarCalibration)
    """The car's calibration (``racer calibrate``'s car.json): effects between the command and the wheels.
    Held inline, so a run's config.json carries it to every worker; no effects = the car as modelled."""
    race: RaceConfig = Field(default_factory=RaceConfig)
    """The race type (time trial, object avoidance, head-to-bot) with its obstacles, bot cars and evaluation
    penalties (``common/race.py``)."""
    condition: WorldCondition = Field(default_factory=WorldCondition)
    """A held-out condition the env is driven in (evaluation only; training leaves it off)."""
    observation: Observation = "sensors"
    """What the env returns: ``sensors``, the model_metadata sensors' observation (the camera, with its LiDAR);
    ``state``, the car's privileged state on the track (``common.privileged.state_vector``, no rendering), what a
    teacher run (``racer train --teacher``) learns from."""


class WorkerEnv(_Strict):
    """What one rollout worker changes in the run's env (DRfC's ``worker-N.env``); None = the run's own.

    The network, the reward function and the action space are the run's: only the world a worker drives in
    differs, as in DRfC's multi-config training (``scripts/training/prepare-config.py`` writes per worker the
    world, race type, start and direction settings and the race's obstacles and bot cars)."""

    track: str | None = None
    """The worker's track (a name or a .npy path)."""
    race: RaceConfig | None = None
    """The worker's race type with its obstacles and bot cars."""
    randomization: RandomizationConfig | None = None
    """The worker's domain randomization, start positions and driving direction."""

    def apply(self, env: EnvConfig) -> EnvConfig:
        """``env`` with this worker's settings in place of the run's."""
        update = {name: getattr(self, name) for name in ("track", "race", "randomization")}
        return env.model_copy(update={k: v for k, v in update.items() if v is not None})

    def describe(self) -> str:
        """One line of what differs from the run (``run's env`` when nothing does)."""
        parts = [f"track {self.track}"] if self.track else []
        if self.race is not None:
            parts.append(f"race {self.race.race_type.value}")
        if self.randomization is not None:
            parts.append("own randomization")
        return ", ".join(parts) or "the run's env"


class DistillConfig(_Strict):
    """A student run's teacher (``racer train --teacher``, docs/teacher.md): the camera network learns to act as a
    privileged teacher (a run of ``observation`` ``state``) does, then, optionally, goes on with PPO on the reward.

    Workers act with the student, or, on a share of the steps, with the teacher (DAgger's mixture: early on the
    student alone would drive off the track before it saw the corners), and label every step with the teacher's
    action distribution; the trainer minimizes KL(teacher ‖ student) (``trainer/distill.py``)."""

    teacher: str = Field(pattern=r"^[A-Za-z0-9._-]+:[0-9]+$")
    """The teacher's checkpoint, ``RUN:VERSION`` in the same store; the trainer copies it into this run
    (``model_store/runs.py: teacher_key``) when the run is created, and workers read that copy."""
    updates: int = Field(40, ge=1)
    """Distillation updates (policy versions 1..updates); PPO on the reward follows while ``fine_tune``."""
    teacher_share: float = Field(0.5, ge=0, le=1)
    """The share of steps the workers drive with the teacher's action under policy version 0."""
    teacher_share_updates: int = Field(10, ge=1)
    """Versions over which that share falls linearly to 0 (DAgger's decaying mixture); at most ``updates``, so the
    segments of PPO's versions are all the student's own."""
    fine_tune: bool = True
    """After ``updates``, go on with PPO on the run's reward function (False: stop learning; the trainer ends)."""

    @model_validator(mode="after")
    def _share_ends_first(self) -> DistillConfig:
        if self.teacher_share_updates > self.updates:
            raise ValueError(
                f"teacher_share_updates ({self.teacher_share_updates}) must not exceed updates ({self.updates})"
            )
        return self

    def teacher_share_at(self, version: int) -> float:
        """The share of steps driven with the teacher's action while collecting for ``version``."""
        return self.teacher_share * max(0.0, 1.0 - version / self.teacher_share_updates)

    def distilling(self, version: int) -> bool:
        """Whether the update from ``version`` distills (True) or is PPO's (False)."""
        return version < self.updates


class PretrainedError(UserError, ValueError):
    """A run's ``pretrained`` source it cannot start from (missing, another action space, other network shapes);
    the one-line message names the source and what differs. Raised before start and by the trainer's load."""


class RunConfig(_Strict):
    """Everything that defines a training run; stored as ``config.json`` in the run so that every process
    (and a worker on another machine) builds the same world and network."""

    run_id: str
    """Run identifier: letters, digits, '.', '_' or '-'."""
    env: EnvConfig = Field(default_factory=EnvConfig)
    """The simulated world (track, reward, actions, randomization). Its reward_fn and action_space paths are
    replaced, in every process, by the run's stored reward_function.py and model_metadata.json."""
    hyperparams: Hyperparameters = Field(default_factory=Hyperparameters)
    """DeepRacer's hyperparameters.json (plus racer's PPO knobs)."""
    policy: PolicyConfig = Field(default_factory=PolicyConfig)
    """The network."""
    worker_envs: list[WorkerEnv] = Field(default_factory=list)
    """Per-worker worlds (``--worker-track``, ``--worker-config``, DRfC's DR_TRAIN_MULTI_CONFIG): worker k drives
    ``worker_envs[k % len]`` applied to ``env``; empty = every worker in ``env``. The evaluator drives ``env``."""
    segment_steps: int = Field(32, ge=1, le=MAX_SEGMENT_STEPS)
    """Env steps per segment pushed to Redis."""
    max_policy_lag: int = Field(0, ge=0)
    """The trainer drops segments whose policy is more than this many versions old. 0 = on-policy as in DeepRacer:
    workers wait during a PPO update instead of collecting data that would be dropped."""
    stream_maxlen: int = Field(128, ge=4)
    """Approximate cap of the segment stream, entries (bounds Redis memory: a 32-step segment of the default run is
    ~50 kB on the wire, common/protocol.py)."""
    heartbeat_ttl_s: float = Field(15.0, gt=0)
    """A worker that has not sent a heartbeat for this long is reported silent, seconds."""
    seed: int = 0
    """Base seed: worker k seeds its env j (of ``--envs-per-worker``; 0 with one env) with seed + 1000·k + j
    (``ENV_SEED_STRIDE``), the trainer uses seed."""
    keep_checkpoints: int = Field(5, ge=2)
    """Whole checkpoints kept besides the one ``best`` names (each is ~70 MB with the default CNN and Adam state)."""
    pretrained: str | None = Field(None, pattern=r"^[A-Za-z0-9._-]+:(best|latest|[0-9]+)$")
    """Start from another run's weights, ``RUN:CHECKPOINT`` (best, latest or a version) in the same store: DRfC's
    pretrained model, the console's clone. The optimizer starts fresh; the action space must be the same."""
    distill: DistillConfig | None = None
    """A student run's teacher and schedule (``racer train --teacher``); None = plain PPO."""

    @model_validator(mode="before")
    @classmethod
    def _worker_tracks(cls, data: object) -> object:
        """A config.json written before per-worker configurations had ``worker_tracks`` (names only): read it as
        the same worlds, so such a run still resumes."""
        if isinstance(data, dict) and "worker_tracks" in data:
            data = dict(data)
            tracks = data.pop("worker_tracks") or []
            if "worker_envs" not in data and isinstance(tracks, list):
                data["worker_envs"] = [{"track": t} for t in tracks]
        return data

    def worker_env(self, index: int) -> EnvConfig:
        """The env rollout worker ``index`` (0-based) drives."""
        if not self.worker_envs:
            return self.env
        return self.worker_envs[index % len(self.worker_envs)].apply(self.env)
