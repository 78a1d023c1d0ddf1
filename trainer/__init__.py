"""racer.trainer: the trainer and evaluator roles.

``process`` pulls segments from Redis, runs PPO (``ppo``: the maths, no I/O), writes checkpoints and
metrics.jsonl to the store, publishes policy versions and runs the collapse guard (``racer trainer``);
``evaluator`` scores checkpoints by robust evaluation, writes evaluations/ and moves the ``best`` pointer
(``racer evaluator``, ``racer eval``). See ARCHITECTURE.md.
"""
