"""Base class for every configuration model: unknown fields are errors, values frozen."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, ValidationError


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


def first_error(exc: ValidationError, default: str, skip: int = 0) -> str:
    """``field.path: reason`` of a validation error's first problem, for one-line replies.
    ``skip`` drops leading location parts (a tagged union's tag)."""
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"][skip:]) or default
    return f"{loc}: {err['msg']}"
