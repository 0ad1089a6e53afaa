"""Strict loading of YAML configs into dataclasses.

A typo'd key, a string where a number belongs or a missing required field is reported as a
:class:`~pmsr_nn.errors.ConfigError` naming the dotted path of the offending entry (and the
closest valid key for a typo). Supported field types: ``bool``, ``int``, ``float``, ``str``,
``tuple[float, float]`` (an interval), ``tuple[X, ...]``, ``Literal[...]``, ``X | None``,
nested dataclasses and ``dict`` (a free mapping whose owner checks its keys).

YAML is read by a hardened loader (:func:`load_yaml`, :func:`parse_yaml_value`): UTF-8 only (a
byte-order mark is accepted), at most :data:`MAX_YAML_BYTES`, nesting at most
:data:`MAX_YAML_DEPTH` deep, anchors and aliases that expand to at most
:data:`MAX_YAML_NODES` values (a "billion laughs" file is refused before it is built), no key
written twice in one mapping, and numbers in every notation Python reads (``3e-3``, ``1E+3``,
``1.0e5``, ``.5``, ``0o17``), which YAML 1.1 alone would read as strings.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
from pathlib import Path
from typing import Any, Literal, TypeVar, Union

import yaml

from .errors import ConfigError

T = TypeVar("T")


MAX_YAML_BYTES = 4 * 2**20
"""Largest config file read (4 MiB; the biggest shipped config is a few kB)."""

MAX_YAML_DEPTH = 64
"""Deepest nesting of lists and mappings accepted."""

MAX_YAML_NODES = 20_000
"""Most values a document may hold once its aliases are expanded (the largest shipped config holds
about 400; a huge list is refused as it is read, in well under a second)."""


class _StrictLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that bounds nesting and alias expansion and refuses duplicate keys."""

    def __init__(self, stream, where: str):
        super().__init__(stream)
        self.where = where
        self.depth = 0
        self.nodes = 0
        self.open: list[dict] = []  # the nodes being read, outermost first: key or [index], start, children so far

    def compose_node(self, parent, index):
        self.depth += 1
        self.nodes += 1
        if self.open:
            self.open[-1]["children"] += 1
        start = self.peek_event().start_mark
        self.open.append({"key": str(index.value) if isinstance(index, yaml.ScalarNode) else
                          f"[{index}]" if isinstance(index, int) else None,
                          "line": start.line + 1, "at": start.index, "children": 0})
        try:
            if self.depth > MAX_YAML_DEPTH:
                raise ConfigError(f"{self.where}: nested more than {MAX_YAML_DEPTH} levels deep "
                                  f"(line {start.line + 1})")
            # counted as the file is read, so a huge list is refused at once, not after building it
            if self.nodes > MAX_YAML_NODES:
                raise ConfigError(self._too_many_values())
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1
            self.open.pop()

    def _too_many_values(self) -> str:
        """The error of a document past :data:`MAX_YAML_NODES` values, naming its longest list or mapping."""
        containers = self.open[:-1]
        longest = max(range(len(containers)), key=lambda i: containers[i]["children"])
        key = ""
        for frame in containers[1 : longest + 1]:  # a.b[3].c
            if frame["key"] is not None:
                key += frame["key"] if frame["key"].startswith("[") or not key else f".{frame['key']}"
        count = _flow_list_length(self.buffer, containers[longest]["at"])
        what = f"is a list of {count:,} values" if count is not None else f"holds more than {MAX_YAML_NODES:,} values"
        return (f"{self.where}: {key or 'the document'} (line {containers[longest]['line']}) {what}; a config holds a "
                f"few hundred values in all (at most {MAX_YAML_NODES:,}): is a long list pasted where a few numbers "
                "belong?")

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                    continue
                key = self.construct_object(key_node)
                if key in seen:
                    raise ConfigError(f"{self.where}: duplicate key {_short(key)} (lines {seen[key]} and "
                                      f"{key_node.start_mark.line + 1}); keep one")
                seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


# YAML 1.1 reads 3e-3, 1e-7 and 1.0e5 as strings (its floats need a dot and a signed exponent),
# and 0o17 as a string; read them as the numbers every config author means.
_StrictLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))
_StrictLoader.add_implicit_resolver(
    "tag:yaml.org,2002:int", re.compile(r"^[-+]?0o[0-7_]+$"), list("-+0"))


def _flow_list_length(text: str, start: int) -> int | None:
    """Items of the flow list ``[a, b, ...]`` that opens at ``text[start]`` when it holds plain scalars
    only (no nested lists or mappings, quotes or comments), else None: counted in the text, at once."""
    if text[start : start + 1] != "[":
        return None
    end = text.find("]", start)
    body = text[start + 1 : end] if end > 0 else ""
    if end < 0 or any(c in body for c in "[{\"'#"):
        return None
    items = body.split(",")
    return len(items) - (not items[-1].strip())  # a trailing comma ends no item


def _expanded_size(root, where: str) -> int:
    """Number of values ``root`` holds with its aliases expanded; refuses recursive aliases.

    Iterative and memoised per node, so it costs one pass over the distinct nodes however large
    the expansion is.
    """
    size: dict[int, int] = {}
    active: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            children = _children(node)
            size[key] = min(1 + sum(size[id(c)] for c in children), MAX_YAML_NODES + 1)
            active.discard(key)
            continue
        if key in size:
            continue
        if key in active:
            raise ConfigError(f"{where}: an alias refers to itself (line {node.start_mark.line + 1})")
        active.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in _children(node) if id(c) not in size)
    return size[id(root)]


def _children(node) -> list:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _parse_yaml(text: str, where: str):
    loader = _StrictLoader(text, where)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if _expanded_size(node, where) > MAX_YAML_NODES:
            raise ConfigError(f"{where}: its anchors and aliases expand to more than {MAX_YAML_NODES:,} values "
                              "(a YAML alias bomb?); write the values out instead")
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or type(exc).__name__
        raise ConfigError(f"{where}: not valid YAML{line}: {problem}") from None
    finally:
        loader.dispose()


def parse_yaml_value(text: str, where: str = "value"):
    """One YAML value (e.g. the right-hand side of a KEY=VALUE override), read by the hardened loader."""
    if len(text) > MAX_YAML_BYTES:
        raise ConfigError(f"{where}: longer than {MAX_YAML_BYTES // 2**20} MiB")
    return _parse_yaml(text, where)


def read_text_file(path: str | Path, what: str = "file", max_bytes: int | None = None) -> str:
    """A UTF-8 text file (byte-order mark dropped), with one-line errors for every way it can fail."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{what} {p} is a folder, not a file")
    if not p.is_file():
        raise ConfigError(f"{what} not found: {p}")
    try:
        if max_bytes is not None and p.stat().st_size > max_bytes:
            raise ConfigError(f"{p}: {p.stat().st_size:,} bytes; a {what} may hold at most {max_bytes:,}")
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read {what} {p}: {exc.strerror or exc}") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(f"{p}: not UTF-8 text (byte 0x{raw[exc.start]:02x} on line {line}); "
                          "save it as UTF-8") from None


def load_yaml(path: str | Path) -> dict:
    """Read a YAML mapping with the hardened loader; one-line errors for every bad file."""
    p = Path(path)
    data = _parse_yaml(read_text_file(p, "config file", MAX_YAML_BYTES), str(p))
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping of keys to values at the top level")
    return data


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters, for error messages about arbitrary user data."""
    if isinstance(value, (dict, list, tuple)) and len(value) > 8:
        return f"a {type(value).__name__} of {len(value):,} items"
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def from_dict(cls: type[T], data: Any, where: str = "config") -> T:
    """Build dataclass ``cls`` from plain data, checking keys and types recursively."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {_short(data)}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    hints = typing.get_type_hints(cls)
    for key in data:
        if key not in fields:
            close = difflib.get_close_matches(str(key), list(fields), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else f" (valid keys: {', '.join(fields)})"
            raise ConfigError(f"{where}: unknown key '{key}'{hint}")
    kwargs = {}
    for name, f in fields.items():
        if name in data:
            kwargs[name] = _convert(hints[name], data[name], f"{where}.{name}")
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where}: missing required key '{name}'")
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _convert(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(inner[0], value, where)
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"{where}: must be one of {list(args)}, got {_short(value)}")
        return value
    if dataclasses.is_dataclass(tp):
        return from_dict(tp, value, where)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {_short(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            things = "numbers" if all(a in (int, float) for a in args) else "values"
            raise ConfigError(f"{where}: expected {len(args)} {things}, got {len(value):,}")
        return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    if tp is dict or origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a mapping, got {_short(value)}")
        return dict(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {_short(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {_short(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {_short(value)}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {_short(value)}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {_short(value)}")
        return value
    raise TypeError(f"unsupported config field type {tp!r} at {where}")  # a bug in a config class


def to_dict(obj: Any) -> Any:
    """Dataclass -> plain data (tuples become lists), YAML/JSON safe."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.init}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    return obj


def require(cond: bool, message: str) -> None:
    """Raise a :class:`ConfigError` with ``message`` unless ``cond`` holds."""
    if not cond:
        raise ConfigError(message)


def check_interval(name: str, lo_hi: tuple[float, float], *, positive: bool = False, nonneg: bool = False) -> None:
    """Validate an interval ``[lo, hi]`` with ``lo <= hi`` and an optional sign constraint."""
    lo, hi = lo_hi
    require(lo <= hi, f"{name}: lower end {lo} exceeds upper end {hi}")
    if positive:
        require(lo > 0, f"{name}: must be positive, got [{lo}, {hi}]")
    if nonneg:
        require(lo >= 0, f"{name}: must be non-negative, got [{lo}, {hi}]")
