"""A newcomer's first steps: the README's set-up text names what each documented ``make``
target needs beyond Python (the programs a recipe runs that are neither the virtualenv's nor
the shell's), and the SDK that Getting started generates in the checkout is left alone by
``make test`` (git-ignored, so ``ruff check .`` skips it)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

from doc_examples import ROOT, extract

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


def sdk_output_path() -> str:
    """Where Getting started's example generates the SDK (``--output-path``)."""
    paths = [m.group(1) for e in extract(ROOT / "docs" / "getting_started.rst")
             for m in re.finditer(r"--output-path\s+(\S+)", e.code)]
    assert len(paths) == 1, paths
    return paths[0]


def test_generated_sdk_is_ignored_by_git_and_ruff(tmp_path):
    """``make test`` starts with ``ruff check .``: a client generated where the docs say must
    not be linted (715 errors when it was ``otgeo_client/`` at the top) nor be untracked."""
    output = sdk_output_path()
    assert not Path(output).is_absolute() and ".." not in Path(output).parts, output
    for name in (".gitignore", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)
    generated = tmp_path / output / "api" / "operations" / "create_job.py"
    generated.parent.mkdir(parents=True)
    generated.write_text("import os\nx=1;y=2\n")  # what ruff would flag (F401, E702)
    (tmp_path / "ok.py").write_text("X = 1\n")
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    ignored = subprocess.run(["git", "check-ignore", "-q", str(generated)], cwd=tmp_path)
    assert ignored.returncode == 0, f"{output} is not git-ignored"
    ruff = Path(sys.executable).parent / "ruff"
    lint = subprocess.run([str(ruff), "check", "--no-cache", "."], cwd=tmp_path,
                          capture_output=True, text=True)
    assert lint.returncode == 0, lint.stdout + lint.stderr
