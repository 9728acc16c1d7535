"""TOML for configuration dataclasses: a small writer, and the standard reader.

    dumps(cfg)  ->  text: one `key = value` per field, its metadata "help" as a comment above it,
                    a `[table]` per nested dataclass (after the table's own keys)
    loads(text) ->  dict (tomllib; tomli on Python 3.10)

TOML has no null: a field holding None is written as a comment (`# name: not set`) and so is absent
on reading, which gives the field's default back. The writer therefore refuses None in a field
whose default is not None (it could not come back). Tuples are written as arrays; the reader
returns lists, which the dataclass turns back into tuples (`reings.config.convert`).
"""
from __future__ import annotations

import math
import re
import textwrap
from dataclasses import MISSING, fields, is_dataclass

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def loads(text: str) -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    return tomllib.loads(text)


def dumps(obj, title: str = "", width: int = 100) -> str:
    if not is_dataclass(obj) or isinstance(obj, type):
        raise TypeError(f"dumps needs a dataclass instance, got {type(obj).__name__}")
    lines = [f"# {title}"] if title else []
    _table(obj, [], lines, width)
    return "\n".join(lines).lstrip("\n") + "\n"


def _table(obj, path: list, lines: list, width: int) -> None:
    tables = []
    for f in fields(obj):
        v = getattr(obj, f.name)
        if is_dataclass(v):
            tables.append((f, v))
            continue
        lines += _comment(f.metadata.get("help", ""), width)
        if v is None:
            if f.default is not None or f.default_factory is not MISSING:
                raise ValueError(f"{'.'.join(path + [f.name])}: None cannot be written to TOML "
                                 f"(absent would read back as the default {f.default!r})")
            lines.append(f"# {_key(f.name)}: not set")
        else:
            lines.append(f"{_key(f.name)} = {value(v)}")
    for f, v in tables:
        lines.append("")
        lines += _comment(f.metadata.get("help", ""), width)
        lines.append("[" + ".".join(_key(k) for k in path + [f.name]) + "]")
        _table(v, path + [f.name], lines, width)


def _comment(text: str, width: int) -> list:
    text = " ".join(str(text).split())
    return ["# " + ln for ln in textwrap.wrap(text, width - 2)] if text else []


def _key(k: str) -> str:
    return k if _BARE_KEY.match(k) else string(k)


def string(s: str) -> str:
    """A TOML basic string (control characters and DEL escaped)."""
    out = []
    for ch in s:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def value(v) -> str:
    """A TOML value: bool, int, float (repr: round-trips exactly; inf, nan), str, list/tuple."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {type(v).__name__} {v!r}")
