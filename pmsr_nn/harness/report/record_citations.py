"""Figures quoted in the documents' prose, each a link to its record that names the key::

    BP scores [24.3](results/one_sky_bp/results.json "cases/one_sky/methods/BP/gospa_m") m

The link text is the quoted figure; the link target the record (relative to the document, as any
Markdown link); the title the key, the path of names through the record's objects (``/`` between
them, a list's index as a number), optionally followed by `` x FACTOR`` where the document quotes
the value scaled (``x 1000`` for seconds quoted in ms, ``x 100`` for a share quoted in %).
:func:`problems` checks that every such citation in a document resolves: the file exists, the key
exists, and the figure equals the record's value rounded to the figure's decimals (a tie either way).
"""

from __future__ import annotations

import json
import re
from decimal import ROUND_HALF_UP, Decimal
from dataclasses import dataclass
from pathlib import Path

CITATION = re.compile(r'\[(?P<figure>[-+]?\d[\d,]*(?:\.\d+)?)\]\((?P<path>[^)\s]+\.json) "(?P<key>[^"]+)"\)')
"""A figure linked to a JSON record with its key as the link's title."""


@dataclass(frozen=True)
class Citation:
    document: str
    line: int
    figure: str
    path: str
    """The record as the document links it (relative to the document)."""
    key: str


def citations(text: str, document: str = "") -> list[Citation]:
    """Every citation of ``text`` (a Markdown document), in order."""
    return [Citation(document, text.count("\n", 0, m.start()) + 1, m["figure"], m["path"], m["key"])
            for m in CITATION.finditer(text)]


def value(record: object, key: str) -> float:
    """The number at ``key`` ("a/b/0/c", optionally " x FACTOR") of a loaded record; KeyError naming
    the first missing part."""
    path, _, factor = key.partition(" x ")
    node = record
    for part in path.split("/"):
        if isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            raise KeyError(f"no {part!r} in {path!r}")
    if isinstance(node, bool) or not isinstance(node, (int, float)):
        raise KeyError(f"{path!r} is not a number")
    return node * float(factor) if factor else node


def rounded(x: float, figure: str, half_up: bool = False) -> str:
    """``x`` written with as many decimals as ``figure`` (thousands separators as ``figure`` has them):
    as Python formats the float, or with ``half_up`` a tie of its shortest decimal text rounded away
    from zero (1.085 -> 1.09, where the float 1.08499... formats as 1.08)."""
    decimals = len(figure.split(".")[1]) if "." in figure else 0
    if half_up:
        x = float(Decimal(repr(x)).quantize(Decimal(1).scaleb(-decimals), rounding=ROUND_HALF_UP))
    text = f"{x:,.{decimals}f}" if "," in figure else f"{x:.{decimals}f}"
    return ("+" + text) if figure.startswith("+") and x >= 0 else text


def quotes(x: float, figure: str) -> bool:
    """Whether ``figure`` is ``x`` at ``figure``'s rounding (either way of rounding a tie)."""
    return figure in (rounded(x, figure), rounded(x, figure, half_up=True))


def problems(document: Path, root: Path) -> list[str]:
    """``document:line: ...`` for each citation of ``document`` that does not resolve or quotes
    another figure than its record's; ``root``: the repository (records must lie inside it)."""
    out, records = [], {}
    rel = document.relative_to(root).as_posix()
    for c in citations(document.read_text(), rel):
        where = f"{rel}:{c.line}: [{c.figure}]({c.path} \"{c.key}\")"
        file = (document.parent / c.path).resolve()
        if not file.is_relative_to(root.resolve()) or not file.is_file():
            out.append(f"{where}: no record {c.path}")
            continue
        if file not in records:
            records[file] = json.loads(file.read_text())
        try:
            x = value(records[file], c.key)
        except (KeyError, ValueError) as exc:
            out.append(f"{where}: {exc}")
            continue
        if not quotes(x, c.figure):
            out.append(f"{where}: the record gives {x!r} ({rounded(x, c.figure)})")
    return out
