"""Pages generated from the code: the API reference of every public name of ``solvers``,
the settings table (from :class:`service.settings.Settings`) and the list of service
operations (from the OpenAPI document), so none of them can drift from what ships.

They are written before Sphinx reads the sources (``config-inited``) into files that git
ignores (``api/index.rst``, ``service/settings_table.rst``, ``service/routes_table.rst``).
"""

from __future__ import annotations

import importlib
import json
import shutil
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
MATHJAX = HERE / "node_modules" / "mathjax" / "es5" / "tex-svg.js"

# The public packages of the library, in the order of the thesis.
PACKAGES = [
    ("solvers.domains", "Domains (§2.2, §3.4)"),
    ("solvers", "Errors"),
    ("solvers.emd", "Earth mover's distances (chapter 2)"),
    ("solvers.convolutional", "Convolutional transport (chapter 3)"),
    ("solvers.transport", "Exact transport and the default decision"),
    ("solvers.softmaps", "Soft maps (chapter 4, §3.7)"),
    ("solvers.histograms", "Histograms on graphs (chapter 5)"),
    ("solvers.color", "Color transfer (§3.7)"),
    ("solvers.convolutional.brdf", "BRDF interpolation (§3.7)"),
    ("solvers.convolutional.skeleton", "Skeleton layout (§3.7)"),
    ("solvers.convolutional.hemisphere", "Hemisphere domain (§3.7)"),
    ("solvers.regularization", "Regularization policy"),
    ("solvers.kernels", "Heat kernels"),
    ("solvers.linalg", "Sparse factorizations"),
    ("solvers.geodesics", "Exact geodesics"),
    ("solvers.validation", "Input validation"),
    ("solvers.monitor", "Progress and results"),
]


def public_names(module_name: str) -> list[str]:
    """``__all__`` of a package, else its public callables and classes defined there."""
    module = importlib.import_module(module_name)
    names = getattr(module, "__all__", None)
    if names is None:
        names = [n for n, v in vars(module).items()
                 if not n.startswith("_") and getattr(v, "__module__", None) == module_name
                 and callable(v)]
    return sorted(names, key=str.lower)


def api_reference() -> str:
    lines = ["API reference", "=============", "",
             "Every public name of the library, generated from the packages' ``__all__``.",
             "Each solver's docstring states its objective, the thesis equation it solves,",
             "its array shapes and the result it returns.", ""]
    seen: set[int] = set()  # a name re-exported by a parent package is documented once
    for package, title in PACKAGES:
        module = importlib.import_module(package)
        names = [n for n in public_names(package) if id(getattr(module, n)) not in seen]
        seen.update(id(getattr(module, n)) for n in names)
        if not names:
            continue
        lines += [title, "-" * len(title), "", f".. currentmodule:: {package}", "",
                  ".. autosummary::", "   :toctree: generated", ""]
        lines += [f"   {n}" for n in names]
        lines.append("")
    return "\n".join(lines)


def _default(field) -> str:
    from pydantic_core import PydanticUndefined

    if field.default_factory is not None:
        return "(computed)" if field.default_factory.__name__ == "<lambda>" else "(none)"
    if field.default is PydanticUndefined or field.default is None:
        return "(none)"
    return f"``{field.default}``"


def settings_table() -> str:
    from service.settings import Settings

    rows = []
    for name, field in Settings.model_fields.items():
        doc = (field.description or "").replace("\n", " ").replace("|", "\\|")
        rows.append((f"``OTGEO_{name.upper()}``", _default(field), doc or "—"))
    return _list_table(["variable", "default", "meaning"], rows, widths="30 15 55")


def routes_table() -> str:
    from service.cli import openapi_document

    spec = json.loads(openapi_document())
    rows = []
    for path, methods in spec["paths"].items():
        for method, op in methods.items():
            summary = (op.get("summary") or "").replace("\n", " ").replace("|", "\\|")
            rows.append((f"``{method.upper()} {path}``", f"``{op['operationId']}``", summary))
    return _list_table(["route", "operation id", "what it does"], rows, widths="38 22 40")


def _list_table(header: list[str], rows: list[tuple[str, ...]], widths: str) -> str:
    out = [".. list-table::", "   :header-rows: 1", f"   :widths: {widths}", ""]
    for row in [tuple(header), *rows]:
        out.append(f"   * - {row[0]}")
        out += [f"     - {cell}" for cell in row[1:]]
    return "\n".join(out) + "\n"


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != text:  # unchanged files keep Sphinx's cache
        path.write_text(text)


def benchmark_pages() -> dict[str, str]:
    """One page per record in bench/results/*.md, included as it is."""
    pages = {}
    for record in sorted((HERE.parent / "bench" / "results").glob("*.md")):
        pages[record.stem] = ("```{include} ../../bench/results/" + record.name +
                              "\n:relative-images:\n:relative-docs: ../\n```\n")
    return pages


def generate(app, config) -> None:
    shutil.rmtree(HERE / "api" / "generated", ignore_errors=True)  # names removed since
    _write(HERE / "api" / "index.rst", api_reference())
    _write(HERE / "service" / "settings_table.rst", settings_table())
    _write(HERE / "service" / "routes_table.rst", routes_table())
    shutil.rmtree(HERE / "benchmarks", ignore_errors=True)
    for name, text in benchmark_pages().items():
        _write(HERE / "benchmarks" / f"{name}.md", text)


def copy_mathjax(app) -> None:
    if not MATHJAX.exists():
        from sphinx.errors import ConfigError

        raise ConfigError(f"{MATHJAX} is missing: run `npm ci` in docs/ (make docs does)")
    target = Path(app.outdir) / "_static" / "mathjax"
    target.mkdir(parents=True, exist_ok=True)
    shutil.copy2(MATHJAX, target / "tex-svg.js")


def setup(app):
    app.connect("config-inited", generate)
    app.connect("builder-inited", copy_mathjax)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
