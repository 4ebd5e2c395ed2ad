"""Generated blocks inside a generated page: one benchmark writes a section of another's page
(production.py writes the 1920x1080 table into docs/error_vs_time.md, beside that page's
160x120 table), and the page's own benchmark keeps the section when it rewrites the page.

A block is the lines between ``<!-- NAME:begin -->`` and ``<!-- NAME:end -->``, markers
included.
"""
from __future__ import annotations

import os
from typing import List, Optional


def markers(name: str) -> tuple:
    """The begin and end marker lines of block ``name``."""
    return f"<!-- {name}:begin -->", f"<!-- {name}:end -->"


def find_block(text: str, name: str) -> Optional[str]:
    """Block ``name`` of ``text``, markers included, or None where it has no whole one."""
    begin, end = markers(name)
    a = text.find(begin)
    if a < 0:
        return None
    b = text.find(end, a + len(begin))
    if b < 0:
        return None
    return text[a:b + len(end)]


def block(name: str, lines: List[str]) -> str:
    """``lines`` as block ``name``."""
    begin, end = markers(name)
    return "\n".join([begin] + list(lines) + [end])


def put_block(path: str, name: str, lines: List[str], after: str = "## Summary") -> bool:
    """Write ``lines`` as block ``name`` into the page at ``path``: in place of the block it
    holds, else before its first line that starts with ``after``, else at its end.  False,
    and nothing written, where the page does not exist."""
    if not os.path.exists(path):
        return False
    with open(path) as f:
        text = f.read()
    new = block(name, lines)
    old = find_block(text, name)
    if old is not None:
        text = text.replace(old, new, 1)
    else:
        rows = text.split("\n")
        at = next((i for i, row in enumerate(rows) if row.startswith(after)), None)
        if at is None:
            text = text.rstrip("\n") + "\n\n" + new + "\n"
        else:
            text = "\n".join(rows[:at] + [new, ""] + rows[at:])
    with open(path, "w") as f:
        f.write(text)
    return True


def kept_block(path: str, name: str) -> List[str]:
    """Block ``name`` of the page at ``path`` as lines (markers included), followed by an
    empty line, for a benchmark that rewrites the page to carry it over; [] where the page
    or the block is missing."""
    if not os.path.exists(path):
        return []
    with open(path) as f:
        got = find_block(f.read(), name)
    return [] if got is None else got.split("\n") + [""]
