"""The cells of the tables written from records (:mod:`.record_tables`): numbers formatted as the
documents write them, and a Markdown row."""

from __future__ import annotations

import math


def fixed(x: float, decimals: int) -> str:
    return f"{x:.{decimals}f}"


def significant(x: float, digits: int) -> str:
    """``x`` to ``digits`` significant figures, without an exponent (48.3 -> "48", 1.416 -> "1.4")."""
    decimals = max(digits - 1 - math.floor(math.log10(abs(x))), 0)
    return f"{x:.{decimals}f}"


def scientific(x: float, decimals: int = 2) -> str:
    """``1.56e4``: the mantissa to ``decimals``, the exponent without sign padding."""
    mantissa, exponent = f"{x:.{decimals}e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def pm(x: float, se: float, decimals: int = 1) -> str:
    return f"{x:.{decimals}f} ± {se:.{decimals}f}"


def row(cells: list[str]) -> str:
    """A Markdown table row; an empty cell is written ``| |``, as the documents do."""
    return "|" + "|".join(f" {c} " if c else " " for c in cells) + "|"
