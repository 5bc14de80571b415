"""A minimal TOML writer for the files the campaign hands to ``sfa sim`` and ``sfa faults proxy``.

Only what those files need: top-level tables of scalars, arrays and inline tables (tomllib reads
them back to the same values; tested). Strings are written as TOML basic strings with JSON escapes,
which TOML accepts for the characters JSON escapes.
"""

from __future__ import annotations

import json
import math
from typing import Any

from tools.faults.errors import FaultConfigError


def _value(v: Any, where: str) -> str:
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
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x, where) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x, where)}" for k, x in v.items()) + " }"
    raise FaultConfigError(f"{where}: cannot write {type(v).__name__} to TOML")


def _key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "_-" for c in k) else json.dumps(k)


def dumps(data: dict[str, Any]) -> str:
    """TOML text for ``data``: top-level scalars first, then one ``[table]`` per dict value."""
    lines = [f"{_key(k)} = {_value(v, k)}" for k, v in data.items() if not isinstance(v, dict)]
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(f"\n[{_key(k)}]")
            lines += [f"{_key(kk)} = {_value(vv, f'{k}.{kk}')}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"
