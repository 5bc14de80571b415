"""``FIELD=VALUE`` command-line items (FilterConfig overrides: ``sfa convert --eval-set``, the
generalisation benchmark's ``--set``) into a dict of numbers and booleans."""

from __future__ import annotations

from tools.errors import ToolError


def parse_field_values(items: list[str], flag: str = "--set") -> dict[str, object]:
    """``["a=1", "b=true", "c=0.5"]`` -> ``{"a": 1, "b": True, "c": 0.5}``; ToolError naming the item."""
    out: dict[str, object] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ToolError(f"{flag} expects FIELD=VALUE, got {item!r}")
        v = value.strip()
        if v.lower() in ("true", "false"):
            out[key.strip()] = v.lower() == "true"
            continue
        try:
            out[key.strip()] = int(v) if v.lstrip("-").isdigit() else float(v)
        except ValueError:
            raise ToolError(f"{flag} {key}: {value!r} is not a number or true/false") from None
    return out
