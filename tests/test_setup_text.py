"""The README's set-up text names what each documented ``make`` target needs beyond Python:
the programs a target's recipe runs that are neither the virtualenv's nor the shell's."""

from __future__ import annotations

import re

from doc_examples import ROOT

SHELL = {"cd", "touch", "[", "echo", "test", "command", "id"}


def recipe_programs(target: str) -> set[str]:
    """First words of the commands of ``target``'s recipe in the Makefile, leaving out make
    variables (the virtualenv's programs: ``$(VENV)/bin/...``, ``$(PY)``) and shell builtins."""
    lines = (ROOT / "Makefile").read_text().splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"{target}:"))
    programs = set()
    for line in lines[start + 1:]:
        if not line.startswith("\t"):
            break
        for command in re.split(r"&&|\|\||;", line.strip().lstrip("@")):
            word = command.split()[0] if command.split() else ""
            if word and not word.startswith("$(") and word not in SHELL:
                programs.add(word)
    return programs


def test_readme_names_what_make_docs_needs():
    setup = (ROOT / "README.md").read_text().split("## ")[0]  # before the first section
    programs = recipe_programs("docs")
    assert "npm" in programs, programs  # what this test is about: docs installs MathJax
    for program in programs:
        assert f"`{program}`" in setup, f"the README's set-up text does not name {program}"
    assert "Node.js" in setup
