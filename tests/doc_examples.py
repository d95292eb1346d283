"""The code examples of documentation files (Markdown or reStructuredText), for the tests
that run them (tests/service/test_readme_examples.py).

Markdown: fenced blocks (```lang or ~~~lang); a block right after a comment
``<!-- include: path/to/file -->`` stands for that file (it must hold the file's text; the
file is what runs). reStructuredText: ``.. code-block:: lang`` / ``.. code:: lang`` /
``.. sourcecode:: lang`` with an indented body, and ``.. literalinclude:: path`` (with
``:language:``, else the file's suffix). Included paths are relative to the document's
folder (as Sphinx reads them; ``/path`` from the repository root). Import from here
(``from doc_examples import extract``)."""

from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LANGUAGES = {"python": "python", "py": "python", "python3": "python",
             "bash": "shell", "sh": "shell", "shell": "shell", "console": "shell",
             "json": "json"}
SUFFIXES = {".py": "python", ".sh": "shell", ".json": "json"}
FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>`{3,}|~{3,})[ \t]*(?P<info>[^`\s]*)")
INCLUDE_COMMENT = re.compile(r"<!--\s*include:\s*(?P<path>\S+)\s*-->")
RST_CODE = re.compile(
    r"^(?P<indent>[ \t]*)\.\. (?:code-block|code|sourcecode)::[ \t]*(?P<lang>\S*)")
RST_INCLUDE = re.compile(r"^(?P<indent>[ \t]*)\.\. literalinclude::[ \t]*(?P<path>\S+)")


@dataclass(frozen=True)
class Example:
    """One code block: where it is, its language (``python``, ``shell``, ``json`` or the
    info string as written), its code, and the file it stands for (includes)."""

    document: Path
    line: int  # 1-based line of the opening fence / directive
    language: str
    code: str
    include: Path | None = None

    @property
    def runnable(self) -> bool:
        return self.language in ("python", "shell", "json")

    @property
    def id(self) -> str:
        """Stable across edits elsewhere in the document: its name and the block's first
        line that is not blank, a comment or an import (or the included file)."""
        if self.include is not None:
            return f"{self.document.name}:{self.include.name}"
        skip = ("#", "import ", "from ")
        first = next((ln.strip() for ln in self.code.splitlines()
                      if ln.strip() and not ln.strip().startswith(skip)
                      and not re.match(r"\w+=\$\{", ln.strip())), "")  # URL=${OTGEO_URL:-...}
        return f"{self.document.name}:{first[:48]}"


def _resolve(document: Path, ref: str) -> Path:
    return (ROOT / ref.lstrip("/")) if ref.startswith("/") else (document.parent / ref).resolve()


def extract(path: Path) -> list[Example]:
    """The code blocks of a Markdown (``.md``) or reStructuredText (``.rst``) file."""
    path = Path(path)
    lines = path.read_text().splitlines()
    return (_rst if path.suffix == ".rst" else _markdown)(path, lines)


def _language(info: str) -> str:
    word = info.strip().lower().lstrip("{").rstrip("}")
    return LANGUAGES.get(word, word)


def _markdown(path: Path, lines: list[str]) -> list[Example]:
    out, i, include = [], 0, None
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            c = INCLUDE_COMMENT.search(lines[i])
            if c:
                include = _resolve(path, c.group("path"))
            elif lines[i].strip():
                include = None
            i += 1
            continue
        fence, start = m.group("fence"), i
        body = []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            body.append(lines[i])
            i += 1
        code = textwrap.dedent("\n".join(body)) + "\n"
        out.append(Example(path, start + 1, _language(m.group("info")), code, include))
        include = None
        i += 1
    return out


def _indented_body(lines: list[str], i: int, indent: str) -> tuple[list[str], list[str], int]:
    """Options (``:name: value``) and body of a directive starting after line ``i - 1``."""
    options, body = [], []
    while i < len(lines) and re.match(rf"^{re.escape(indent)}[ \t]+:\w[\w-]*:", lines[i]):
        options.append(lines[i].strip())
        i += 1
    while i < len(lines) and (not lines[i].strip()
                              or len(lines[i]) - len(lines[i].lstrip()) > len(indent)):
        body.append(lines[i])
        i += 1
    while body and not body[-1].strip():
        body.pop()
    return options, body, i


def _rst(path: Path, lines: list[str]) -> list[Example]:
    out, i = [], 0
    while i < len(lines):
        code, inc = RST_CODE.match(lines[i]), RST_INCLUDE.match(lines[i])
        if not (code or inc):
            i += 1
            continue
        start, indent = i, (code or inc).group("indent")
        options, body, i = _indented_body(lines, i + 1, indent)
        if code:
            text = textwrap.dedent("\n".join(body)).strip("\n") + "\n"
            out.append(Example(path, start + 1, _language(code.group("lang")), text))
        else:
            target = _resolve(path, inc.group("path"))
            lang = next((o.split(":", 2)[2].strip() for o in options
                         if o.startswith(":language:")), None)
            language = _language(lang) if lang else SUFFIXES.get(target.suffix, "")
            out.append(Example(path, start + 1, language, target.read_text(), target))
    return out
