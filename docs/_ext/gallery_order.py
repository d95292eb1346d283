"""Gallery order: by the thesis figure each example names in its title, ``(Fig. 2.12)``.

``sphinx_gallery_conf["within_subsection_order"]`` points here.  The key is
``(chapter, 0, figure, file name)``.  An example that illustrates a section without
claiming one of its figures names the section instead, ``(§4.5``, and goes after the
chapter's figures, by section: ``(chapter, 1, section, file name)``.  An example whose
title names neither goes last, by file name, so a new entry never breaks the build.
"""

from __future__ import annotations

import re
from pathlib import Path

# The first "(Fig. c.f", "(Figs. c.f" or "(§c.s" of the text.
FIGURE = re.compile(r"\((Figs?\.|§)\s*(\d+)\.(\d+)")


def figure_key(text: str, name: str) -> tuple:
    """``(chapter, 0, figure, name)`` of the first ``(Fig. c.f`` in ``text``, ``(chapter,
    1, section, name)`` of a first ``(§c.s``; neither: last."""
    match = FIGURE.search(text)
    if match is None:
        return (float("inf"), float("inf"), float("inf"), name)
    kind = 1 if match.group(1) == "§" else 0
    return (int(match.group(2)), kind, int(match.group(3)), name)


class FigureNumberSortKey:
    """Sort the examples of ``src_dir`` by the figure number in their docstring's title."""

    def __init__(self, src_dir):
        self.src_dir = Path(src_dir)

    def __repr__(self) -> str:  # sphinx-gallery hashes the config through repr
        return "<FigureNumberSortKey>"

    def __call__(self, filename) -> tuple:
        path = self.src_dir / filename
        head = path.read_text(encoding="utf-8")[:600] if path.is_file() else ""
        return figure_key(head, str(filename))
