"""The ``racer`` commands, one module per group (train, roles, evaluate, models, deploy, calibrate, tracks, bench).

Each command parses its options, calls one function of the package and prints what it returned. None catches
errors: a :class:`common.errors.UserError` becomes a one-line message and exit code 2 in ``racer/cli.py``.
"""
