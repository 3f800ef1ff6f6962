"""What the saved-result tests compare (tests/data/results/): a saved JSON against today's, key by
key, numbers to rounding. Its own module so that a test beside its expensive fixture (the spindle
twin check in tests/test_twin.py) compares the same way as tests/test_saved_results.py."""

from __future__ import annotations

import json
import math
from pathlib import Path

SAVED = Path(__file__).resolve().parent / "data" / "results"


def differences(saved, now, where: str = "") -> list[str]:
    """Where ``now`` differs from ``saved``: a key missing or added, a type, a string, a number
    beyond rounding, a list's length."""
    if isinstance(saved, dict) and isinstance(now, dict):
        out = [f"{where}/{k}: missing" for k in saved.keys() - now.keys()]
        out += [f"{where}/{k}: added" for k in now.keys() - saved.keys()]
        for k in saved.keys() & now.keys():
            out += differences(saved[k], now[k], f"{where}/{k}")
        return out
    if isinstance(saved, list) and isinstance(now, list):
        if len(saved) != len(now):
            return [f"{where}: {len(saved)} items saved, {len(now)} now"]
        return [d for i, (a, b) in enumerate(zip(saved, now)) for d in differences(a, b, f"{where}[{i}]")]
    numbers = (int, float)
    if isinstance(saved, numbers) and isinstance(now, numbers) and not isinstance(saved, bool):
        ok = math.isclose(saved, now, rel_tol=1e-9, abs_tol=1e-15) or (math.isnan(saved) and math.isnan(now))
        return [] if ok else [f"{where}: {saved!r} saved, {now!r} now"]
    return [] if saved == now and type(saved) is type(now) else [f"{where}: {saved!r} saved, {now!r} now"]


def key_paths(obj, where: str = "") -> set[str]:
    """Every key path of ``obj`` (a list's items merged under ``[]``): the shape a reader relies on."""
    if isinstance(obj, dict):
        return {p for k, v in obj.items() for p in {f"{where}/{k}"} | key_paths(v, f"{where}/{k}")}
    if isinstance(obj, list):
        return {p for item in obj for p in key_paths(item, f"{where}[]")}
    return set()


def saved_file(name: str) -> dict:
    return json.loads((SAVED / name).read_text())


def with_paths(obj, paths: dict[str, str]):
    """``obj`` with each of ``paths`` replaced by its value in every string."""
    if isinstance(obj, dict):
        return {k: with_paths(v, paths) for k, v in obj.items()}
    if isinstance(obj, list):
        return [with_paths(v, paths) for v in obj]
    if isinstance(obj, str):
        for old, new in paths.items():
            obj = obj.replace(old, new)
    return obj
