"""Numbers written for people: rounded to their precision, not printed with 16 digits.

:func:`format_with_std` writes an estimate with its standard deviation, both rounded to two
significant digits of the standard deviation (the convention of the GUM, JCGM 100:2008 7.2.6);
:func:`format_sig` writes a number without a known precision to a few significant digits.
"""

from __future__ import annotations

import math

import numpy as np


def decimals_for(std: float, digits: int = 2) -> int:
    """Return the number of decimals that keeps ``digits`` significant digits of ``std`` (may be negative)."""
    if not np.isfinite(std) or std <= 0:
        return 6
    return digits - 1 - math.floor(math.log10(abs(std)))


def format_with_std(value: float, std: float, digits: int = 2, unit: str = "", sign: bool = False) -> str:
    """Return ``"value +- std unit"``, both rounded to ``digits`` significant digits of ``std``.

    >>> format_with_std(6.932989123, 1.74e-5, unit="m")
    '6.932989 +- 0.000017 m'
    """
    d = decimals_for(std, digits)
    sgn = "+" if sign else ""
    if d >= 0:
        text = f"{value:{sgn}.{d}f} +- {std:.{d}f}"
    else:  # std of tens or more: round both to its leading digits
        q = 10.0 ** (-d)
        text = f"{round(value / q) * q:{sgn}.0f} +- {round(std / q) * q:.0f}"
    return f"{text} {unit}".rstrip()


def finite_or_none(v) -> float | None:
    """Return ``v`` as a float, or None when it is not finite (JSON has no inf or nan)."""
    v = float(v)
    return v if math.isfinite(v) else None


def format_sig(value, digits: int = 3) -> str:
    """Return ``value`` with ``digits`` significant digits (``"inf"``, ``"nan"`` as such); lists and
    arrays element by element in brackets, dicts entry by entry in braces, other values as ``str``."""
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {format_sig(v, digits)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(format_sig(v, digits) for v in np.ravel(value)) + "]"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        return str(value)
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if not np.isfinite(value):
        return str(float(value))
    return f"{value:.{digits}g}"
