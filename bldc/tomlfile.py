"""Strict TOML files: every TOML file the framework reads goes through ``load_toml``.

Plant files, budgets, campaign specs, device profiles, trace and gate mappings and effect lists
are all read here, so they share one error type, ``TomlError``, and one way of saying where: the
file, the line when the TOML parser knows it, the table in TOML's own notation and the key::

    limits.toml: [commutation_angle_p99].limt: unknown key (known: description, kind, ...)
    limits.toml: [[waiver]][0].because: unknown key (known: expires, owner, ...)
    plant.toml: not valid TOML: Expected ']' at the end of a table declaration (at line 1, column 7)

A *schema* says which keys a file may hold; an unknown key is refused with the keys that are
known. Values are the reader's to check (it raises ``TomlError`` or its own error naming the key).

- ``None``: any content;
- a set of names: a table holding only those keys (their values are not looked into);
- a dict of name -> schema: a table holding only those keys, each checked against its schema;
  the name ``"*"`` stands for any other key;
- a one-element list ``[schema]``: an array of tables (``[[name]]``), each checked against it.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

from .params import ConfigError

#: any other key of a table (a schema dict's key)
ANY_KEY = "*"


class TomlError(ConfigError):
    """A TOML file that cannot be used. ``file``, ``line`` (when the parser knows it), ``table``
    (``[name]``, ``[a.b]``, ``[[name]][i]``; None at the top level) and ``key`` say where; ``field``
    (``ConfigError``) is all of it as the message shows it."""

    def __init__(self, file: str | Path, message: str, *, table: str | None = None, key: str | None = None,
                 line: int | None = None):
        self.file, self.table, self.key, self.line = str(file), table, key, line
        place = ".".join(p for p in (table, key) if p)
        super().__init__(f"{self.file}: {place}" if place else self.file, message)


def _decode_line(exc: tomllib.TOMLDecodeError) -> int | None:
    """The line tomllib reports (an attribute from Python 3.14 on, before that in the message)."""
    line = getattr(exc, "lineno", None)
    if line is None and (m := re.search(r"\(at line (\d+), column \d+\)", str(exc))):
        line = int(m.group(1))
    return line


def load_toml(path: str | Path, schema: Any = None, *, name: str | None = None) -> dict:
    """The tables of the TOML file ``path`` after checking its keys against ``schema`` (module
    docstring). Errors name the file as ``name`` (default: ``path`` as given)."""
    where = name or str(path)
    try:
        text = Path(path).read_bytes().decode("utf-8-sig")  # TOML is UTF-8; a byte-order mark is tolerated
    except OSError as exc:
        raise TomlError(where, f"cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise TomlError(where, f"not UTF-8 text (byte {exc.start}): TOML files are UTF-8") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TomlError(where, f"not valid TOML: {exc}", line=_decode_line(exc)) from None
    check_keys(data, schema, where)
    return data


def _table_label(at: str | None, key: str) -> str:
    """TOML's name of the table ``key`` inside the table ``at``: ``[a]``, ``[a.b]``, ``[[w]][0].b``."""
    if at is None:
        return f"[{key}]"
    if at.startswith("[") and not at.startswith("[[") and at.endswith("]"):
        return f"[{at[1:-1]}.{key}]"
    return f"{at}.{key}"


def check_keys(table: dict, schema: Any, file: str, at: str | None = None) -> None:
    """Refuse a key of ``table`` (the table ``at`` of ``file``, None: the top level) that ``schema``
    does not know, and a value that is not the table or array of tables it says, recursively."""
    if schema is None:
        return
    known = set(schema) - {ANY_KEY}
    for key, value in table.items():
        if key not in known and ANY_KEY not in schema:
            raise TomlError(file, f"unknown key (known: {', '.join(sorted(known))})", table=at, key=key)
        sub = schema.get(key, schema.get(ANY_KEY)) if isinstance(schema, dict) else None
        if sub is None:
            continue
        label = _table_label(at, key)
        if isinstance(sub, list):
            if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
                raise TomlError(file, f"an array of tables: write [{label}]", table=at, key=key)
            for i, t in enumerate(value):
                check_keys(t, sub[0], file, f"[{label}][{i}]" if at is None else f"{label}[{i}]")
        elif not isinstance(value, dict):
            raise TomlError(file, f"must be a table ({label}), got {value!r}", table=at, key=key)
        else:
            check_keys(value, sub, file, label)
