"""racer: the ``racer`` command line and what it orchestrates.

``cli`` is the typer app (thin: each command parses options and calls one function); ``launcher`` and
``embedded_redis`` run ``racer train`` (Redis, trainer, workers, evaluator as processes); ``runconfig``,
``check`` and ``drfc`` turn the user's files into a run; ``evaluate``, ``plots``, ``limit``, ``calibrate``
back the other commands, and the ``bench`` package holds the benchmarks. See ARCHITECTURE.md.
"""
