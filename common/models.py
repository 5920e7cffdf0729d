"""Base class for every configuration model: unknown fields are errors, values frozen.

Numbers in files are strict: ``Real`` takes an int or a float and nothing else (a string
such as ``"63"`` or a YAML boolean is refused, not coerced) and never NaN or infinity;
``Integer`` takes an int only (not ``10.0``, not ``true``). Every numeric field of a model
read from a file uses one of them (tests/unit/test_hostile_files.py walks the models to check).
"""

from __future__ import annotations

from typing import Annotated

from pydantic import AllowInfNan, BaseModel, ConfigDict, Field, Strict, ValidationError

Real = Annotated[float, Strict(), AllowInfNan(False)]
Integer = Annotated[int, Strict()]
Port = Annotated[Integer, Field(ge=1, le=65535)]
Host = Annotated[str, Field(min_length=1, max_length=253, pattern=r"^[A-Za-z0-9.:_-]+$")]


class FieldError(ValueError):
    """A model validator's finding about one field (``field``: dotted, relative to the
    model that raises it), reported at that field instead of at the model."""

    def __init__(self, field: str, reason: str):
        super().__init__(f"{field}: {reason}")
        self.field, self.reason = field, reason


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


def first_error(exc: ValidationError, default: str, skip: int = 0) -> str:
    """``field.path: reason`` of a validation error's first problem, for one-line replies.
    ``skip`` drops leading location parts (a tagged union's tag)."""
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err["loc"][skip:]) or default
    return f"{loc}: {err['msg']}"
