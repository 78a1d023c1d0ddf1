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
"""``racer train``'s evaluation starts per direction when neither ``--eval-episodes`` nor a DRfC folder's
DR_EVAL_NUMBER_OF_TRIALS says."""
