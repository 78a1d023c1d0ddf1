"""Defaults that several layers share, kept in one place."""

DEFAULT_TRACK = "racer_loop"
"""The track every command uses when none is given: one of racer's own generated tracks (``sim/track_gen.py``), so
a fresh machine trains with no download and no network."""

STRAIGHT_TRACK = "racer_straight"
"""racer's open track (a straight line, no lap), for what needs a track without a lap."""

MAX_SEGMENT_STEPS = 4096
"""The most env steps one segment may carry: the bound of ``RunConfig.segment_steps``, and what the trainer's decoder
accepts (it bounds the memory a segment's compressed frames may expand to)."""

DEFAULT_WORKERS = 2
"""``racer train``'s rollout workers when neither ``--workers`` nor a DRfC folder's DR_WORKERS says."""

DEFAULT_EVAL_EPISODES = 3
"""The evaluator's starts per direction beside training (``racer train``, ``racer evaluator``, compose) when neither
``--eval-episodes`` nor a DRfC folder's DR_EVAL_NUMBER_OF_TRIALS says: it shares the machine with the training."""

CHECK_EPISODES = 6
"""Starts per direction of an evaluation on demand (``racer eval``, ``trainer.evaluator.EvalSettings``): twice the
evaluator's, as nothing else needs the CPU then."""

EVAL_ACTION_NOISE = 0.1
"""Uniform noise on the commands of an evaluation (``trainer.evaluator.EvalSettings``, ``racer eval``, ``racer
evaluator``), as in the env's randomization: 0.1 = ±3° steering, ±10 % speed."""

DEFAULT_EVAL_NICE = 5
"""The evaluator's nice increment beside training (``racer train``, ``racer evaluator``, compose): it yields the CPU
to the trainer and the workers, yet still takes a share (an evaluation during a PPO update slowed it by up to ~50 %)."""

DEFAULT_TRAINER_THREADS = 2
"""PyTorch threads of the trainer (``racer train``, ``racer trainer``, compose): with max_policy_lag 0 the workers
wait while it trains, so it can use two."""

DEFAULT_GIVE_UP_S = 600.0
"""How long a role process waits through one Redis or store outage before it exits with an error, seconds
(``--outage-timeout``)."""
