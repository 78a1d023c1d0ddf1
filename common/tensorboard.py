"""TensorBoard without TensorFlow, in every racer process.

TensorBoard's ``tensorboard.compat.tf`` imports all of TensorFlow when it can find it, which it can once the
``deepracer`` extra is installed; ``torch.utils.tensorboard`` (the trainer's event files) and Stable-Baselines3's
logger (``racer bench train``) both reach it. That costs about 4 s and a few hundred MB a process, and worse:
TensorFlow's LLVM and Mesa's (llvmpipe, behind MuJoCo's EGL renderer) cannot share a process, which dies loading
the second (a static initializer of ``libtensorflow_framework.so``). TensorBoard uses its own stub of TensorFlow's
file API instead when a module ``tensorboard.compat.notf`` exists (``tensorboard/compat/__init__.py: tf``), which
is what it does anyway without TensorFlow installed: the event files are the same. Only racer's DeepRacer model
formats (``deploy/deepracer_graph.py``) import TensorFlow, in ``racer export`` and ``racer import`` processes.
"""

from __future__ import annotations

import sys
import types

NO_TENSORFLOW = "tensorboard.compat.notf"
"""The module whose presence makes TensorBoard use its TensorFlow stub."""


def tensorboard_without_tensorflow() -> None:
    """Make TensorBoard use its stub of TensorFlow in this process; call before anything imports TensorBoard."""
    sys.modules.setdefault(NO_TENSORFLOW, types.ModuleType(NO_TENSORFLOW))
