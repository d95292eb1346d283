"""tests/doc_examples.py reads code blocks the same way from Markdown and reStructuredText
(the README today, a Sphinx docs tree later): languages, bodies, includes."""

from __future__ import annotations

from doc_examples import ROOT, extract


def test_markdown_blocks_and_includes(tmp_path):
    (tmp_path / "ex.py").write_text("print(1)\n")
    doc = tmp_path / "doc.md"
    doc.write_text("Text\n\n```bash\necho hi\n```\n\n<!-- include: ex.py -->\n```python\n"
                   "print(1)\n```\n\n~~~json\n{\"kind\": \"grid\"}\n~~~\n\n```text\nout\n```\n")
    blocks = extract(doc)
    assert [(b.language, b.code) for b in blocks] == [
        ("shell", "echo hi\n"), ("python", "print(1)\n"), ("json", '{"kind": "grid"}\n'),
        ("text", "out\n")]
    assert blocks[1].include == tmp_path / "ex.py" and blocks[0].include is None
    assert [b.runnable for b in blocks] == [True, True, True, False]
    assert blocks[0].line == 3


def test_rst_code_blocks_and_literalinclude(tmp_path):
    (tmp_path / "ex.py").write_text("x = 1\n")
    doc = tmp_path / "doc.rst"
    doc.write_text("Title\n=====\n\n.. code-block:: python\n   :caption: a\n\n   import os\n"
                   "   print(os.sep)\n\nText.\n\n.. code:: bash\n\n   ls\n\n"
                   ".. literalinclude:: ex.py\n\n.. literalinclude:: /examples/quickstart.py\n"
                   "   :language: python\n")
    blocks = extract(doc)
    assert [(b.language, b.code) for b in blocks[:3]] == [
        ("python", "import os\nprint(os.sep)\n"), ("shell", "ls\n"), ("python", "x = 1\n")]
    assert blocks[2].include == tmp_path / "ex.py"
    assert blocks[3].include == ROOT / "examples" / "quickstart.py"
    assert blocks[3].code == (ROOT / "examples" / "quickstart.py").read_text()
