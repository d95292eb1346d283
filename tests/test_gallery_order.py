"""The gallery lists its examples in the thesis' figure order (docs/_ext/gallery_order.py)."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "_ext"))
from gallery_order import FigureNumberSortKey, figure_key  # noqa: E402

GALLERY = ROOT / "examples" / "gallery"


def test_figure_key_orders_numerically_and_puts_unnumbered_last():
    titles = {"b.py": "A (Fig. 2.12)", "a.py": "B (Fig. 2.3)", "c.py": "C (Figs. 10.1 and 10.2)",
              "d.py": "no figure"}
    order = sorted(titles, key=lambda f: figure_key(titles[f], f))
    assert order == ["a.py", "b.py", "c.py", "d.py"]  # 2.3 < 2.12 < 10.1, by number


def test_section_titles_go_after_their_chapters_figures_by_section():
    titles = {"a.py": "A (§4.6)", "b.py": "B (§4.5, eq. 4.2)", "c.py": "C (Fig. 4.13)",
              "d.py": "D (Fig. 5.2)", "e.py": "E (Fig. 4.6)", "f.py": "no figure"}
    order = sorted(titles, key=lambda f: figure_key(titles[f], f))
    assert order == ["e.py", "c.py", "b.py", "a.py", "d.py", "f.py"]


def test_the_first_reference_in_the_text_decides():
    assert figure_key("T (§4.5)\n\nas in (Fig. 3.14)", "x.py")[:3] == (4, 1, 5)
    assert figure_key("T (Fig. 3.14)\n\nsee (§4.5)", "x.py")[:3] == (3, 0, 14)


def test_every_gallery_example_names_its_figure_or_section():
    key = FigureNumberSortKey(GALLERY)
    for path in GALLERY.glob("plot_*.py"):
        chapter = key(path.name)[0]
        assert chapter != float("inf"), f"{path.name}: no '(Fig. c.f)' or '(§c.s)' in its title"
