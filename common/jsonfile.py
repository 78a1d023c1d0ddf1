"""Reading a user's JSON settings file with one-line errors that name the file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def read_json_object(path: str | Path, label: str, error: type[Exception]) -> dict[str, Any]:
    """The JSON object in ``path``; otherwise ``error("<label> '<path>' does not exist" / "is not valid JSON: …" /
    ": expected a JSON object, got list")``."""
    p = Path(path)
    where = f"{label} {str(p)!r}"
    try:
        data = json.loads(p.read_text())
    except FileNotFoundError:
        raise error(f"{where} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{where} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise error(f"{where}: expected a JSON object, got {type(data).__name__}")
    return data
