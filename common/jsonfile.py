"""Reading a user's JSON settings file with one-line errors that name the file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from common.errors import first_validation_error

M = TypeVar("M", bound=BaseModel)


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


def load_json_model(path: str | Path, label: str, model: type[M], error: type[Exception]) -> M:
    """``model`` validated from the JSON object in ``path``; otherwise ``error`` with one line naming the file and
    the first bad field: ``<label> '<path>': <field>: <reason>``."""
    data = read_json_object(path, label, error)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise error(f"{label} {str(path)!r}: {first_validation_error(exc)}") from None
