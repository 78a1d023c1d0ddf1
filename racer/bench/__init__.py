"""The benchmarks behind the figures in the README and docs/, one module per ``racer bench`` command.

``env`` (env steps/s and its parts), ``worker`` (a rollout worker with K envs), ``update`` (a PPO minibatch step
against the GEMM peak), ``wire`` (bytes a worker sends and downloads), ``loop`` (``transport`` and end-to-end
throughput), ``scale`` (1…64 workers' load on one trainer), ``soak`` (a long run's memory), ``view`` (the cost of
``racer view``), ``train`` (time to a robust lap against SB3 PPO), ``race`` (racing against ``racer limit``), ``oa``
(object avoidance and head-to-bot), ``calibrate`` (the time of ``racer calibrate``) and ``transfer`` (the DeepRacer
paper's Table II in simulation). Each module's ``command`` checks the command's options (bad ones raise
:class:`common.errors.OptionError`), runs the benchmark and returns a :class:`Report`; ``racer/commands/bench.py``
only registers the commands, parses their options and shows the report.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from rich.table import Table


@dataclass
class Report:
    """What a benchmark command shows: its result (what ``--json`` writes) and the tables and lines it prints, in
    order."""

    result: Any
    shown: list[Table | str] = field(default_factory=list)


def figures_table(figures: dict[str, Any], float_format: str) -> Table:
    """A two-column table of ``figures``, floats in ``float_format``."""
    table = Table("figure", "value")
    for k, v in figures.items():
        table.add_row(k, float_format.format(v) if isinstance(v, float) else str(v))
    return table
