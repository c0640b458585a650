"""One table printer for benchmarks, notebooks and reports: aligned plain text or
Markdown, floats to three significant digits."""
from __future__ import annotations

from collections.abc import Sequence


def cell(v: object) -> str:
    """A value as a table shows it: floats to three significant digits (large ones whole),
    lists joined by commas."""
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.0f}"
    if isinstance(v, (list, tuple)):
        return ", ".join(cell(x) for x in v) or "-"
    return str(v)


def format_table(header: Sequence[str], rows: Sequence[Sequence[object]], indent: int = 3,
                 rule: bool = False) -> list[str]:
    """Lines of an aligned text table: the first column left-aligned, the others right;
    ``rule`` draws a line under the header."""
    cells = [list(map(str, header))] + [[cell(v) for v in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = [" " * indent + "  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths)))
             for r in cells]
    if rule:
        lines.insert(1, " " * indent + "-" * (len(lines[0]) - indent))
    return lines


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)
