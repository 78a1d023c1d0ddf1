"""Which torch device the trainer and the evaluator compute on: ``--device auto|cpu|cuda|cuda:N``.

``auto`` is the first CUDA device where torch sees one (``torch.cuda.is_available()``), else the CPU. The rollout
workers always act on the CPU (one process per core, a batch of one frame: a GPU would not pay). Every command that
takes ``--device`` resolves it here, so a bad value is the same one-line error everywhere.

torch is imported only inside :func:`resolve_device`: ``racer train``'s launcher checks the spelling with
:func:`check_device` without loading torch (about 1.3 s and 220 MB it would keep for the whole run).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from common.errors import OptionError

if TYPE_CHECKING:
    import torch

DEVICE_HELP = (
    "Where the trainer (and the evaluator) compute: auto (the first CUDA GPU if torch sees one, else the CPU), cpu, "
    "cuda or cuda:N. The rollout workers always run on the CPU."
)

_SPELLING = re.compile(r"auto|cpu|cuda(:\d+)?")


def check_device(name: str) -> str:
    """``name`` if it is spelled as a device (``auto``, ``cpu``, ``cuda``, ``cuda:N``), without importing torch;
    OptionError naming ``--device`` and the value otherwise. Whether the machine has that device is
    :func:`resolve_device`'s question."""
    if not _SPELLING.fullmatch(name):
        raise OptionError(f"--device must be auto, cpu, cuda or cuda:N (got {name!r})")
    return name


def resolve_device(name: str) -> torch.device:
    """The torch device ``--device name`` means on this machine; OptionError naming ``--device`` and the value for a
    misspelt name, CUDA where torch has none, or a GPU index beyond the GPUs torch sees."""
    import torch

    check_device(name)
    if name == "auto":
        return torch.device("cuda", 0) if torch.cuda.is_available() else torch.device("cpu")
    if name == "cpu":
        return torch.device("cpu")
    if not torch.cuda.is_available():
        why = "no CUDA build" if torch.version.cuda is None else "no GPU visible (driver, CUDA_VISIBLE_DEVICES)"
        raise OptionError(f"--device {name}: torch {torch.__version__} has no CUDA device here ({why})")
    index = int(name.partition(":")[2] or 0)
    count = torch.cuda.device_count()
    if index >= count:
        raise OptionError(f"--device {name}: torch sees {count} CUDA device(s), cuda:0 to cuda:{count - 1}")
    return torch.device("cuda", index)
