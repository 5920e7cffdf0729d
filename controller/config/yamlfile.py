"""YAML from untrusted files (configs, profiles, task files).

PyYAML's safe loader constructs no Python objects, but it still trusts the shape of a
document: its composer recurses once per nesting level (a few thousand ``[`` end in
RecursionError), an alias is a reference that later code walks as many times as it is
used (a few lines of nested aliases expand to billions of values: "billion laughs"), a
repeated key silently replaces the first one, and ``.nan``, ``.inf`` or ``1e999`` pass as
numbers. This loader composes the document itself, on libyaml's event stream, and refuses
each of these at the node, naming the field and the line:

- nesting deeper than ``MAX_DEPTH`` (a cell config is about 6 levels deep),
- more than ``MAX_NODES`` values once every alias is expanded, an alias to a node that
  contains it (a cycle),
- a key given twice in one mapping,
- a number that is not finite, an integer longer than ``MAX_INT_DIGITS`` digits,
- a NUL character in a string.

Two resolution rules differ from YAML 1.1 as PyYAML applies it, so that a value reads as
what it looks like: ``1e3`` and ``1.5e-3`` are numbers (YAML 1.2; PyYAML wants a dot and a
signed exponent and makes them strings, which strict number fields would then refuse),
and ``2024-01-01`` stays a string (no config field is a date, and an impossible date such
as ``2024-13-45`` made PyYAML raise ValueError).
"""

from __future__ import annotations

import math
import re
from typing import Any

import yaml
from yaml.composer import Composer
from yaml.constructor import SafeConstructor
from yaml.events import AliasEvent, MappingEndEvent, SequenceEndEvent
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode
from yaml.resolver import Resolver

MAX_DEPTH = 32
MAX_NODES = 100_000
MAX_INT_DIGITS = 40

FLOAT = "tag:yaml.org,2002:float"
INT = "tag:yaml.org,2002:int"
STR = "tag:yaml.org,2002:str"
MERGE = "tag:yaml.org,2002:merge"
TIMESTAMP = "tag:yaml.org,2002:timestamp"


class YamlRefused(yaml.YAMLError):
    """A well-formed document this loader will not build: ``field`` (dotted path), the
    position of the node and the reason."""

    def __init__(self, field: str, mark: Any, reason: str):
        super().__init__(reason)
        self.field, self.mark, self.reason = field, mark, reason


class _Resolver(Resolver):
    pass


_Resolver.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag not in (FLOAT, TIMESTAMP)]
    for first, resolvers in Resolver.yaml_implicit_resolvers.items()
}
_Resolver.add_implicit_resolver(FLOAT, re.compile(r"""^(?:
     [-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)[eE][-+]?[0-9]+
    |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""", re.X), list("-+0123456789."))


def dotted(path: list[Any]) -> str:
    return ".".join(str(p) for p in path) or "(top level)"


class _Composer(Composer):
    """PyYAML's composer with the checks above; ``_path`` is where it is in the document."""

    def __init__(self) -> None:
        super().__init__()
        self._path: list[Any] = []
        self._depth = 0
        self._deepest = 0
        self._count = 0  # values so far, aliases expanded
        self._done: dict[str, tuple[int, int]] = {}  # anchor -> (values, height) once composed

    def _refuse(self, mark: Any, reason: str, path: list[Any] | None = None) -> YamlRefused:
        return YamlRefused(dotted(self._path if path is None else path), mark, reason)

    def _counted(self, n: int, mark: Any) -> None:
        self._count += n
        if self._count > MAX_NODES:
            raise self._refuse(mark, f"more than {MAX_NODES} values once aliases are expanded")

    def compose_node(self, parent: Node | None, index: Any) -> Node:
        if self.check_event(AliasEvent):
            return self._alias(self.get_event())
        event = self.peek_event()
        if self._depth >= MAX_DEPTH:
            raise YamlRefused(dotted(self._path[:8]) + ("..." if len(self._path) > 8 else ""), event.start_mark,
                              f"nested more than {MAX_DEPTH} levels deep")
        anchor = event.anchor
        start, deepest = self._count, self._deepest
        self._depth += 1
        self._deepest = self._depth
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        self._counted(1, event.start_mark)
        if anchor is not None:
            self._done[anchor] = (self._count - start, self._deepest - self._depth)
        self._deepest = max(deepest, self._deepest)
        return node

    def _alias(self, event: Any) -> Node:
        node = self.anchors.get(event.anchor)
        if node is None:
            raise self._refuse(event.start_mark, f"alias *{event.anchor} to no anchor")
        if event.anchor not in self._done:
            raise self._refuse(event.start_mark, f"alias *{event.anchor} inside the node it names (a cycle)")
        values, height = self._done[event.anchor]
        if self._depth + height > MAX_DEPTH:
            raise self._refuse(event.start_mark, f"alias *{event.anchor} nests more than {MAX_DEPTH} levels deep")
        self._counted(values, event.start_mark)
        self._deepest = max(self._deepest, self._depth + height)
        return node

    def compose_scalar_node(self, anchor: str | None) -> ScalarNode:
        node = super().compose_scalar_node(anchor)
        value = node.value
        if node.tag == FLOAT and not math.isfinite(SafeConstructor.construct_yaml_float(self, node)):
            raise self._refuse(node.start_mark, f"{value!r} is not a finite number")
        if node.tag == INT and len(value) > MAX_INT_DIGITS:
            raise self._refuse(node.start_mark, f"an integer of more than {MAX_INT_DIGITS} digits")
        if "\0" in value:
            raise self._refuse(node.start_mark, "a NUL character in a string")
        return node

    def compose_sequence_node(self, anchor: str | None) -> SequenceNode:
        start = self.get_event()
        tag = start.tag
        if tag is None or tag == "!":
            tag = self.resolve(SequenceNode, None, start.implicit)
        node = SequenceNode(tag, [], start.start_mark, None, flow_style=start.flow_style)
        if anchor is not None:
            self.anchors[anchor] = node
        while not self.check_event(SequenceEndEvent):
            self._path.append(len(node.value))
            node.value.append(self.compose_node(node, len(node.value)))
            self._path.pop()
        node.end_mark = self.get_event().end_mark
        return node

    def compose_mapping_node(self, anchor: str | None) -> MappingNode:
        start = self.get_event()
        tag = start.tag
        if tag is None or tag == "!":
            tag = self.resolve(MappingNode, None, start.implicit)
        node = MappingNode(tag, [], start.start_mark, None, flow_style=start.flow_style)
        if anchor is not None:
            self.anchors[anchor] = node
        seen: dict[tuple[str, str], Any] = {}
        while not self.check_event(MappingEndEvent):
            key = self.compose_node(node, None)
            name = key.value if isinstance(key, ScalarNode) else "?"
            if isinstance(key, ScalarNode) and key.tag != MERGE:
                first = seen.setdefault((key.tag, key.value), key.start_mark)
                if first is not key.start_mark:
                    raise self._refuse(key.start_mark, f"key {name!r} given twice (first at line {first.line + 1})",
                                       self._path + [name])
            self._path.append(name)
            value = self.compose_node(node, key)
            self._path.pop()
            node.value.append((key, value))
        node.end_mark = self.get_event().end_mark
        return node


_Parser = getattr(yaml, "CParser", None)

if _Parser is not None:
    class _Loader(_Composer, _Parser, SafeConstructor, _Resolver):  # type: ignore[misc, valid-type]
        def __init__(self, stream: str) -> None:
            _Parser.__init__(self, stream)
            _Composer.__init__(self)
            SafeConstructor.__init__(self)
            _Resolver.__init__(self)
else:  # pragma: no cover - PyYAML built without libyaml
    from yaml.parser import Parser
    from yaml.reader import Reader
    from yaml.scanner import Scanner

    class _Loader(Reader, Scanner, Parser, _Composer, SafeConstructor, _Resolver):  # type: ignore[no-redef]
        def __init__(self, stream: str) -> None:
            Reader.__init__(self, stream)
            Scanner.__init__(self)
            Parser.__init__(self)
            _Composer.__init__(self)
            SafeConstructor.__init__(self)
            _Resolver.__init__(self)


def parse(text: str) -> Any:
    """The one document in ``text`` (None when empty). Raises ``yaml.YAMLError`` for a
    syntax error and ``YamlRefused`` for a document refused above; ``ValueError`` when an
    explicitly tagged value cannot be built (``!!int abc``)."""
    loader = _Loader(text)
    try:
        return loader.get_single_data()
    except (TypeError, OverflowError) as exc:
        raise ValueError(str(exc)) from exc
    finally:
        loader.dispose()


__all__ = ["MAX_DEPTH", "MAX_NODES", "YamlRefused", "parse", "dotted"]
