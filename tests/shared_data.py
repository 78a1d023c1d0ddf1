"""Where the tests find public DeepRacer data that the repository must not hold, and how they skip without it.

DeepRacer's route files, its public Gazebo logs and community JSON files are read in place from
``../shared/data`` beside the project's root (``RACER_SHARED_DATA`` names another folder). A test that needs them
calls :func:`shared_data` (or carries :data:`needs_deepracer_tracks`), which skips it, saying what is missing,
when the folder is absent. The rest of the suite runs on racer's own tracks and data.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED_DATA = Path(os.environ.get("RACER_SHARED_DATA") or REPO.parent / "shared" / "data")
SHARED_TRACKS = SHARED_DATA / "tracks"
HAVE_DEEPRACER_TRACKS = SHARED_TRACKS.is_dir()

needs_deepracer_tracks = pytest.mark.skipif(
    not HAVE_DEEPRACER_TRACKS,
    reason=f"DeepRacer's route files are read from {SHARED_TRACKS}, which is absent (set RACER_SHARED_DATA)",
)
"""Mark a test that loads DeepRacer's tracks by name (``reinvent_base``, ``Spain_track``, ...)."""


def shared_data(*parts: str) -> Path:
    """The path of public data under the shared folder; skips the calling test, naming it, when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(
            f"public DeepRacer data {path} is absent (read in place from ../shared/data; set RACER_SHARED_DATA)"
        )
    return path


def deepracer_track_names() -> list[str]:
    """The DeepRacer route names the shared folder holds (empty without it), for parametrizing."""
    if not HAVE_DEEPRACER_TRACKS:
        return []
    return sorted(p.stem for p in SHARED_TRACKS.glob("*.npy"))
