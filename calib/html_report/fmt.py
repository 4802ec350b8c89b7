"""Number and HTML formatting shared by the report's sections.

Every string that comes from a result goes through :func:`text` (``html.escape``); numbers
go through the ``num_*`` helpers, which print a fixed, sensible precision, a real minus sign,
and an em dash for a missing or non-finite value.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Mapping, Sequence
from html import escape
from typing import Any

MISSING = "—"


def text(value: Any) -> str:
    """Any value as escaped HTML text (``None`` → em dash)."""
    return MISSING if value is None else escape(str(value))


def _finite(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def _minus(s: str) -> str:
    return "−" + s[1:] if s.startswith("-") else s


def num_fixed(value: Any, decimals: int = 3) -> str:
    """Fixed decimals, e.g. ``0.226`` [mm]; ``∞`` for infinity, em dash when missing."""
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isinf(value):
        return "∞" if value > 0 else "−∞"
    v = _finite(value)
    if v is None:
        return MISSING
    if abs(v) >= 1e7:
        return num_sci(v)
    s = f"{v:.{decimals}f}"
    if float(s) == 0.0:
        s = s.lstrip("-")
    return _minus(s)


def num_sig(value: Any, digits: int = 2) -> str:
    """Significant digits, for uncertainties: ``0.0041``, ``1.3``, ``250``."""
    v = _finite(value)
    if v is None:
        return MISSING
    if v == 0:
        return "0"
    if abs(v) >= 1e6 or abs(v) < 1e-4:
        return num_sci(v, digits)
    shift = digits - 1 - math.floor(math.log10(abs(v)))
    return _minus(f"{round(v, shift):.{max(0, shift)}f}")


def sigma_decimals(sigma: Any, digits: int = 2) -> int:
    """Decimal places of ``sigma`` rounded to ``digits`` significant digits (≥ 0)."""
    v = _finite(sigma)
    if v is None or v == 0:
        return 6
    return max(0, digits - 1 - math.floor(math.log10(abs(v))))


def num_sci(value: Any, digits: int = 3) -> str:
    """Scientific notation as HTML: ``1.23 × 10<sup>8</sup>``."""
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isinf(value):
        return "∞"
    v = _finite(value)
    if v is None:
        return MISSING
    if v == 0:
        return "0"
    mantissa, exponent = f"{v:.{digits - 1}e}".split("e")
    return f"{_minus(mantissa)} × 10<sup>{_minus(str(int(exponent)))}</sup>"


def num_int(value: Any) -> str:
    v = _finite(value)
    return MISSING if v is None else f"{round(v):d}"


def yes_no(value: Any, yes: str = "yes", no: str = "no") -> str:
    """A boolean as a coloured word (the word carries the meaning, not the colour)."""
    if value is None:
        return MISSING
    return f'<span class="ok">{yes}</span>' if value else f'<span class="bad">{no}</span>'


def names_list(names: Iterable[Any]) -> str:
    """Parameter names as escaped, comma-separated ``<code>``; em dash when empty."""
    items = [f"<code>{text(n)}</code>" for n in names]
    return ", ".join(items) if items else MISSING


def get_map(result: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    """``result[key]`` when it is a mapping, else an empty one (older or partial results)."""
    value = result.get(key)
    return value if isinstance(value, Mapping) else {}


def get_list(result: Mapping[str, Any], key: str) -> list[Any]:
    value = result.get(key)
    return list(value) if isinstance(value, list | tuple) else []


def table(
    css_class: str, headers: Sequence[str], rows: Iterable[str], numeric: Collection[int] = ()
) -> str:
    """A ``<table>`` with one header row; ``headers`` are HTML (units in brackets), the
    columns whose index is in ``numeric`` are right-aligned, ``rows`` are ``<tr>`` strings."""
    num = ' class="num"'
    head = "".join(
        f'<th scope="col"{num if k in numeric else ""}>{h}</th>' for k, h in enumerate(headers)
    )
    return (
        f'<table class="{css_class}"><thead><tr>{head}</tr></thead>'
        f"<tbody>{''.join(rows)}</tbody></table>"
    )
