"""The suite collects under pytest's default (rootdir-relative basename) import mode, which
refuses two test modules with one basename in different folders: keep basenames unique."""
from collections import Counter
from pathlib import Path


def test_test_module_basenames_are_unique():
    names = Counter(p.name for p in Path(__file__).parent.rglob("test_*.py"))
    assert [n for n, c in names.items() if c > 1] == []
