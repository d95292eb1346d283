"""Every public name of the library has a numpydoc docstring (issue 41, item 6).

The public names are those of the API reference (``docs/_ext/otgeo_docs.py``: the
``__all__`` of ``solvers`` and its packages, and the public callables of the modules it
lists). numpydoc's own parser reads each docstring; a name fails when

* a function or method that takes parameters has no ``Parameters`` section, or leaves a
  parameter of its signature out of it (``a, b : type`` documents both);
* a function that returns (or yields) a value has no ``Returns`` (``Yields``) section;
* a class has neither a ``Parameters`` nor an ``Attributes`` section, or leaves a
  parameter of its constructor out of both (protocols have no constructor; a class that
  inherits a library base's constructor unchanged is held to the base's docstring);
* numpydoc warns while parsing it (an unknown or malformed section), or a type line
  leaves an inline literal open.

Methods are the public ones of a public class (inherited ones from the library too), each
checked once; an override with its base's parameters is held to its base's docstring (the
contract is documented once, where it is declared); properties take no parameters and are
not checked.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import sys
import textwrap
import warnings
from pathlib import Path

from numpydoc.docscrape import ClassDoc, FunctionDoc

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs" / "_ext"))
import otgeo_docs  # noqa: E402


def public_objects():
    """``(qualified name, object)`` of each public function and class, each object once."""
    seen: set[int] = set()
    for package, _ in otgeo_docs.PACKAGES:
        module = importlib.import_module(package)
        for name in otgeo_docs.public_names(package):
            obj = getattr(module, name)
            if id(obj) in seen or not (inspect.isclass(obj) or inspect.isfunction(obj)):
                continue  # constants (DOMAIN_KINDS, ...) have no docstring of their own
            seen.add(id(obj))
            yield f"{package}.{name}", obj


def public_methods(cls):
    """``(name, function, static)`` of the public methods of ``cls`` defined in the library."""
    for name in dir(cls):
        if name.startswith("_"):
            continue
        raw = inspect.getattr_static(cls, name)
        func = raw.__func__ if isinstance(raw, (classmethod, staticmethod)) else raw
        if inspect.isfunction(func) and func.__module__.startswith("solvers"):
            yield name, func, isinstance(raw, staticmethod)


def overridden(cls, name: str, func):
    """The method of a base class of ``cls`` that ``func`` overrides with the same
    parameters, or None: an override keeps the contract its base documents."""
    owner = next(c for c in cls.__mro__ if name in vars(c))
    for base in owner.__mro__[1:]:
        raw = vars(base).get(name)
        base_func = raw.__func__ if isinstance(raw, (classmethod, staticmethod)) else raw
        if inspect.isfunction(base_func):
            same = list(inspect.signature(base_func).parameters) == list(
                inspect.signature(func).parameters)
            return base_func if same else None
    return None


def _parameters(func, bound: bool) -> list[str]:
    """The names a docstring must document: the signature's, less ``self``/``cls``."""
    names = list(inspect.signature(func).parameters)
    names = names[1:] if bound and names else names
    return [n for n in names if not n.startswith("_")]  # private keywords stay private


def _documented(doc, *sections: str) -> set[str]:
    """Names documented in ``sections``, with ``a, b : type`` split and ``*`` stripped."""
    names = set()
    for section in sections:
        for param in doc[section]:
            names.update(n.strip().lstrip("*") for n in param.name.split(","))
    return names


def _returns_value(func) -> bool:
    """Whether ``func``'s own body returns a value or yields (nested functions aside)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(func)))
    except (OSError, TypeError):
        return inspect.signature(func).return_annotation not in (None, "None")
    body = tree.body[0]

    def walk(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda,
                                  ast.ClassDef)):
                continue
            yield child
            yield from walk(child)

    return any((isinstance(n, ast.Return) and n.value is not None
                and not (isinstance(n.value, ast.Constant) and n.value.value is None))
               or isinstance(n, (ast.Yield, ast.YieldFrom)) for n in walk(body))


def _parse(kind, obj, **kw):
    """Parse with numpydoc; its warnings are problems of the docstring, and so is a type
    line whose inline literal is left open (numpydoc cuts a wrapped type line: Sphinx
    then warns "Inline literal start-string without end-string")."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        doc = kind(obj, **kw)
    problems = [str(w.message).splitlines()[0] for w in caught]
    for section in ("Parameters", "Returns", "Yields", "Attributes"):
        problems += [f"open inline literal in the {section} type line {p.type!r}"
                     for p in doc[section] if p.type.count("``") % 2]
    return doc, problems


def function_problems(func, bound: bool = False, check_returns: bool = True) -> list[str]:
    doc, problems = _parse(FunctionDoc, func)
    params = _parameters(func, bound)
    if params:
        if not doc["Parameters"]:
            problems.append("no Parameters section")
        else:
            missing = [p for p in params if p not in _documented(doc, "Parameters")]
            if missing:
                problems.append(f"parameters not documented: {missing}")
    if check_returns and _returns_value(func) and not (doc["Returns"] or doc["Yields"]):
        problems.append("no Returns section")
    return problems


def inherited_constructor(cls):
    """The library base class whose constructor ``cls`` inherits unchanged (an exception
    subclass, say), or None: such a class is held to its base's Parameters."""
    init = cls.__dict__.get("__init__")
    if init is not None or dataclasses.is_dataclass(cls):
        return None
    for base in cls.__mro__[1:]:
        if "__init__" in base.__dict__:
            return base if base.__module__.startswith("solvers") else None
    return None


def class_problems(cls) -> list[str]:
    base = inherited_constructor(cls)
    if base is not None:
        return class_problems(base)
    doc, problems = _parse(ClassDoc, cls, config={"show_class_members": False})
    if not (doc["Parameters"] or doc["Attributes"]):
        problems.append("no Parameters or Attributes section")
    else:
        try:
            params = [p for p in inspect.signature(cls).parameters if not p.startswith("_")]
        except (TypeError, ValueError):
            params = []
        if getattr(cls, "_is_protocol", False):
            params = []  # a typing.Protocol is never constructed
        missing = [p for p in params if p not in _documented(doc, "Parameters", "Attributes")]
        if missing:
            problems.append(f"constructor parameters not documented: {missing}")
    return problems


def undocumented() -> dict[str, list[str]]:
    """Every public name (and method) whose docstring fails, with its problems."""
    failures: dict[str, list[str]] = {}
    methods_seen: set[int] = set()
    for qualname, obj in public_objects():
        if inspect.isfunction(obj):
            problems = function_problems(obj)
        else:
            problems = class_problems(obj)
            for name, func, static in public_methods(obj):
                if id(func) in methods_seen:
                    continue
                methods_seen.add(id(func))
                base = overridden(obj, name, func)
                method_problems = function_problems(base or func, bound=not static,
                                                    check_returns=False)
                if method_problems:
                    failures[f"{qualname}.{name}"] = method_problems
        if problems:
            failures[qualname] = problems
    return failures


def test_the_walk_finds_the_public_names():
    names = dict(public_objects())
    assert "solvers.convolutional.wasserstein_distance" in names
    assert "solvers.domains.TriangleMesh" in names
    assert len(names) > 150
    mesh = names["solvers.domains.TriangleMesh"]
    methods = {name: func for name, func, _ in public_methods(mesh)}
    assert {"heat_kernel", "from_file"} <= set(methods)
    base = names["solvers.domains.Domain"]
    assert overridden(mesh, "ground_distances", methods["ground_distances"]) is (
        base.ground_distances)
    assert overridden(mesh, "from_file", methods["from_file"]) is None
    assert inherited_constructor(names["solvers.DomainError"]) is names["solvers.OTGeoError"]
    assert inherited_constructor(mesh) is None


def test_the_checker_sees_a_missing_section():
    def documented(a, b, *, c=1):
        """One line.

        Parameters
        ----------
        a, b : (n,) array
            Inputs.
        c : int
            A count.

        Returns
        -------
        float
            Their sum.
        """
        return a + b + c

    def lacking(a, b):
        """One line.

        Parameters
        ----------
        a : float
            Only one of two.
        """
        return a + b

    def wrapped(a):
        """One line.

        Parameters
        ----------
        a : float
            A number.

        Returns
        -------
        Result with ``values`` of shape ``(len(rows),
        len(columns))``.
        """
        return a

    assert function_problems(documented) == []
    assert function_problems(lacking) == ["parameters not documented: ['b']",
                                          "no Returns section"]
    assert {p.split(" type line")[0] for p in function_problems(wrapped)} == {
        "open inline literal in the Returns"}  # each half of the cut line is one entry


def test_every_public_name_has_numpydoc_sections():
    failures = undocumented()
    print(f"{len(failures)} undocumented public names")
    report = "\n".join(f"{name}: {'; '.join(p)}" for name, p in sorted(failures.items()))
    assert not failures, f"{len(failures)} undocumented public names:\n{report}"


def test_the_docstring_examples_run():
    """Every ``Examples`` section of a public name runs and prints what it shows."""
    import doctest

    finder, runner = doctest.DocTestFinder(recurse=False), doctest.DocTestRunner()
    ran = []
    for qualname, obj in public_objects():
        if not (obj.__doc__ and "Examples\n" in obj.__doc__):
            continue
        for test in finder.find(obj, qualname, globs={}):
            if test.examples:
                runner.run(test)
                ran.append(qualname)
    assert len(ran) >= 3, ran
    assert runner.summarize(verbose=False).failed == 0
