"""How a request finds what answers it: a handler's method carries the model of the
request it answers (``@answers(GripRequest)``), so a request is written in one place, its
model beside the method. The command socket's requests are the handlers' requests
together: their union, their names and the dispatch table all follow from the methods.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Annotated, Any, Union, get_args

from fluidsense.common.errors import CommandError
from fluidsense.common.models import StrictModel, first_error
from pydantic import Field, TypeAdapter, ValidationError

Reply = dict[str, Any]


def answers(model: type[StrictModel]) -> Callable[[Callable[..., Awaitable[Reply]]], Callable[..., Awaitable[Reply]]]:
    """Marks the method that answers ``model``'s request (its ``cmd`` literal names it)."""

    def mark(method: Callable[..., Awaitable[Reply]]) -> Callable[..., Awaitable[Reply]]:
        method.request_model = model  # type: ignore[attr-defined]
        return method

    return mark


def models_of(*classes: type) -> tuple[type[StrictModel], ...]:
    """The request models the classes' methods answer, in the order they are written."""
    return tuple(fn.request_model for cls in classes for fn in vars(cls).values() if hasattr(fn, "request_model"))


def name_of(model: type[StrictModel]) -> str:
    (name,) = get_args(model.model_fields["cmd"].annotation)
    return name


class Routes:
    """The requests that ``handlers`` answer: a JSON object validated into its model,
    and the bound method that answers it."""

    def __init__(self, *handlers: object):
        models = models_of(*(type(h) for h in handlers))
        self.names = tuple(name_of(m) for m in models)
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"two handlers answer one request: {self.names}")
        # bound from the class: an attribute of the same name on the instance cannot shadow it
        self._methods = {model: fn.__get__(h, type(h)) for h in handlers for fn in vars(type(h)).values()
                         if (model := getattr(fn, "request_model", None)) is not None}
        self._adapter = TypeAdapter(Annotated[Union[models], Field(discriminator="cmd")])  # noqa: UP007 - a tuple of types

    def parse(self, data: dict[str, Any]) -> StrictModel:
        """The request's model; CommandError with a reason for the client."""
        if data.get("cmd") not in self.names:
            raise CommandError(f"unknown command {data.get('cmd')!r}; known: {', '.join(self.names)}")
        try:
            return self._adapter.validate_python(data)
        except ValidationError as exc:
            raise CommandError(first_error(exc, "request", skip=1)) from None

    def method(self, request: StrictModel) -> Callable[[StrictModel], Awaitable[Reply]]:
        return self._methods[type(request)]
