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


def test_every_gallery_example_names_its_figure():
    key = FigureNumberSortKey(GALLERY)
    for path in GALLERY.glob("plot_*.py"):
        chapter, figure, _ = key(path.name)
        assert chapter != float("inf"), f"{path.name}: no '(Fig. c.f)' in its title"
