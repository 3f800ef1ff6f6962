"""Typed, bounded parameters: one declaration serves validation, docs and hypothesis.

A parameter is a dataclass field declared with :func:`bounded`; its metadata holds the unit,
the physical bounds and a one-line meaning. :func:`validate` checks an instance field by field
and raises :class:`ConfigError` naming the offending field, so a TOML file with a NaN or a
negative resistance is refused with a message a person can act on.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping


class ConfigError(ValueError):
    """A configuration value is wrong; ``field`` is the dotted path of the culprit."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"{field}: {message}")


def bounded(
    default: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    unit: str = "",
    doc: str = "",
    integer: bool = False,
    low_open: bool = False,
    length: int | None = None,
):
    """A dataclass field with physical bounds. Tuples are checked element by element."""
    meta = dict(low=low, high=high, unit=unit, doc=doc, integer=integer, low_open=low_open, length=length)
    if isinstance(default, (list, tuple)):
        return dataclasses.field(default_factory=lambda d=tuple(default): d, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _check_scalar(path: str, value: Any, meta: Mapping[str, Any]) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(path, f"expected a number, got {value!r}")
    if meta.get("integer"):
        if isinstance(value, float) and not value.is_integer():
            raise ConfigError(path, f"expected a positive integer, got {value!r}")
        value = int(value)
    if not math.isfinite(value):
        raise ConfigError(path, f"must be finite, got {value!r}")
    low, high = meta.get("low"), meta.get("high")
    unit = meta.get("unit") or ""
    if low is not None:
        if meta.get("low_open") and value <= low:
            raise ConfigError(path, f"must be > {low} {unit}, got {value!r}".replace("  ", " "))
        if value < low:
            raise ConfigError(path, f"must be >= {low} {unit}, got {value!r}".replace("  ", " "))
    if high is not None and value > high:
        raise ConfigError(path, f"must be <= {high} {unit}, got {value!r}".replace("  ", " "))
    return value


def validate(obj: Any, prefix: str = "") -> None:
    """Check every bounded field of a dataclass instance; raise ConfigError on the first bad one."""
    for f in dataclasses.fields(obj):
        meta = f.metadata
        if "unit" not in meta:
            continue
        path = f"{prefix}{f.name}"
        value = getattr(obj, f.name)
        if isinstance(value, (list, tuple)):
            if meta.get("length") is not None and len(value) != meta["length"]:
                raise ConfigError(path, f"expected {meta['length']} values, got {len(value)}")
            for i, v in enumerate(value):
                _check_scalar(f"{path}[{i}]", v, meta)
        else:
            _check_scalar(path, value, meta)


def from_mapping(cls: type, data: Mapping[str, Any], prefix: str = ""):
    """Build dataclass ``cls`` from a mapping (a TOML table), refusing unknown keys by name."""
    names = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs = {}
    for key, value in data.items():
        if key not in names:
            known = ", ".join(sorted(names))
            raise ConfigError(f"{prefix}{key}", f"unknown parameter (known: {known})")
        if isinstance(value, list):
            value = tuple(value)
        kwargs[key] = value
    obj = cls(**kwargs)
    validate(obj, prefix)
    return obj


def describe(cls: type) -> list[dict[str, Any]]:
    """Rows (name, unit, bounds, default, meaning) for docs and error messages."""
    rows = []
    for f in dataclasses.fields(cls):
        if "unit" not in f.metadata:
            continue
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        rows.append(dict(name=f.name, default=default, **f.metadata))
    return rows


def strategy_for(cls: type, **fixed: Any):
    """A hypothesis strategy drawing every bounded field of ``cls`` inside its bounds."""
    from hypothesis import strategies as st

    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in fixed:
            kwargs[f.name] = st.just(fixed[f.name])
            continue
        meta = f.metadata
        if "unit" not in meta or meta.get("low") is None or meta.get("high") is None:
            continue
        if meta.get("integer"):
            scalar = st.integers(int(meta["low"]), int(meta["high"]))
        else:
            scalar = st.floats(
                meta["low"], meta["high"], allow_nan=False, allow_infinity=False,
                exclude_min=bool(meta.get("low_open")),
            )
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        if isinstance(default, tuple):
            n = meta.get("length") or len(default)
            kwargs[f.name] = st.tuples(*([scalar] * n))
        else:
            kwargs[f.name] = scalar
    return st.builds(cls, **kwargs)
