"""The "done when" figures of issue 41 ("One house") for the current tree, from its source.

    python bench/house.py            # the figures, then the sites behind each
    python bench/house.py --summary  # the figures only

Read with ``ast`` (nothing is imported or run), over ``solvers/`` and ``service/``:

- kind branches outside ``solvers/domains/``: comparisons of a kind (a name or attribute
  ``kind``, ``x["kind"]``, ``x.get("kind")``) with domain kind names, ``isinstance`` checks
  against the domain classes of ``solvers/domains/`` (but against the base ``Domain``
  alone: that asks whether an argument is a domain at all, listed apart), and
  ``hasattr``/``getattr`` probes of an attribute that some domain classes define and
  others do not (but probes of a request, ``req.n_nodes``: listed apart);
- ``route`` sites (parameters and class fields named ``route`` or ``*_route``) other than
  the HTTP ones (in ``service/api/``, and an operation's flag saying it has one), grouped
  by what they name (``ROUTE_MEANINGS``: by module), each with the values written there;
- parameters and class fields named ``algorithm`` or ``solver`` (``*_solver`` too);
- functions over 80 lines (docstrings not counted); public functions (no leading underscore
  in their own or their class's name) over 10 parameters (``self``/``cls`` and
  ``*args``/``**kwargs`` not counted);
- import cycles: strongly connected components of the module import graph, with the
  module-level imports only (at import time) and with function-local ones too, and of the
  graph of subpackages (``solvers.emd`` -> ``solvers.histograms``) with every import;
  imports under ``if TYPE_CHECKING:`` are left out;
- ``duplicates`` pairs in ``solvers/`` and in ``service/`` (the ``duplicates`` command).
"""

from __future__ import annotations

import argparse
import ast
import re
import shutil
import subprocess
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("solvers", "service")
DOMAINS_DIR = "solvers/domains/"
KINDS = {"mesh", "grid", "graph", "pointcloud"}
MAX_LINES, MAX_PARAMS = 80, 10
ROUTE_NAME = re.compile(r"^(route|\w+_route)$")
METHOD_NAMES = re.compile(r"^(algorithm|solver|\w+_solver|\w+_algorithm)$")
# isinstance against the base ``Domain`` alone asks whether an argument is a domain at all
# (the histogram solvers also take a sparse weight matrix), which no domain method can
# answer: listed, not counted as a kind branch
NOT_KIND = "isinstance against the base Domain (not counted)"
# hasattr/getattr on an operation's request (``req``, ``request``) probes one of its fields
# that happens to share a name with a domain attribute (``n_nodes``): listed, not counted
REQUEST_NAMES = {"req", "request"}
REQUEST_PROBES = "hasattr/getattr probes of a request's fields (not counted)"
SPEC_CLASSES = {"GridSpec", "GraphSpec", "PointCloudSpec", "MeshSpec"}  # service/schemas.py


@dataclass
class Module:
    name: str
    path: Path
    tree: ast.Module
    rel: str = field(init=False)

    def __post_init__(self):
        self.rel = self.path.relative_to(REPO).as_posix()


def load_modules() -> dict[str, Module]:
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            mods[name] = Module(name, path, ast.parse(path.read_text(), str(path)))
    return mods


def site(mod: Module, node: ast.AST) -> str:
    return f"{mod.rel}:{node.lineno}"


# -- kind branches -------------------------------------------------------------------------


def domain_classes(mods: dict[str, Module]) -> dict[str, set[str]]:
    """``class name -> attribute names`` of the classes of solvers/domains/ that derive from
    ``Domain`` (and ``Domain`` itself), their bases' attributes included."""
    classes, bases = {}, {}
    for mod in mods.values():
        if not mod.rel.startswith(DOMAINS_DIR):
            continue
        for node in ast.walk(mod.tree):
            if isinstance(node, ast.ClassDef):
                classes[node.name] = _class_attributes(node)
                bases[node.name] = [b.id for b in node.bases if isinstance(b, ast.Name)]

    def is_domain(name):
        return name == "Domain" or any(is_domain(b) for b in bases.get(name, ()))

    def attrs(name):
        own = set(classes.get(name, ()))
        return own.union(*(attrs(b) for b in bases.get(name, ())))

    return {name: attrs(name) for name in classes if is_domain(name)}


def _class_attributes(node: ast.ClassDef) -> set[str]:
    names = set()
    for item in node.body:
        if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
            names.add(item.name)
        elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
            names.add(item.target.id)
        elif isinstance(item, ast.Assign):
            names.update(t.id for t in item.targets if isinstance(t, ast.Name))
    for sub in ast.walk(node):  # self.x = ... in methods
        if (isinstance(sub, ast.Attribute) and isinstance(sub.ctx, ast.Store)
                and isinstance(sub.value, ast.Name) and sub.value.id == "self"):
            names.add(sub.attr)
    return names


def _names_kind(node: ast.AST) -> bool:
    """``kind``, ``x.kind``, ``x["kind"]``, ``x.get("kind")``, ``getattr(x, "kind", ...)``."""
    if isinstance(node, ast.Name):
        return node.id == "kind"
    if isinstance(node, ast.Attribute):
        return node.attr == "kind"
    if isinstance(node, ast.Subscript):
        return isinstance(node.slice, ast.Constant) and node.slice.value == "kind"
    if isinstance(node, ast.Call):
        args = node.args
        if isinstance(node.func, ast.Attribute) and node.func.attr == "get":
            return bool(args) and isinstance(args[0], ast.Constant) and args[0].value == "kind"
        if isinstance(node.func, ast.Name) and node.func.id == "getattr":
            return len(args) >= 2 and isinstance(args[1], ast.Constant) and args[1].value == "kind"
    return False


def _names_kinds(node: ast.AST) -> bool:
    """Kind names: string constants naming a kind, or a set of kinds (``EXACT_KINDS``,
    an operation's ``self.kinds``)."""
    if _strings(node) & KINDS:
        return True
    if isinstance(node, ast.Name):
        return node.id.endswith("KINDS")
    return isinstance(node, ast.Attribute) and node.attr == "kinds"


def _strings(node: ast.AST) -> set[str]:
    return {n.value for n in ast.walk(node) if isinstance(n, ast.Constant)
            and isinstance(n.value, str)}


def kind_branches(mods: dict[str, Module]) -> dict[str, list[str]]:
    classes = domain_classes(mods)
    specs = SPEC_CLASSES  # the service's domain specifications, one class per kind
    everywhere = set.intersection(*classes.values()) if classes else set()
    partial = set().union(*classes.values()) - everywhere  # defined by some kinds only
    out = defaultdict(list)
    for mod in mods.values():
        if mod.rel.startswith(DOMAINS_DIR):
            continue
        for node in ast.walk(mod.tree):
            if isinstance(node, ast.Compare):
                sides = [node.left, *node.comparators]
                if any(map(_names_kind, sides)) and any(
                        _names_kinds(s) for s in sides if not _names_kind(s)):
                    out["string comparisons"].append(site(mod, node))
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
                fn, args = node.func.id, node.args
                if fn == "isinstance" and len(args) == 2:
                    named = {n.id if isinstance(n, ast.Name) else n.attr
                             for n in ast.walk(args[1])
                             if isinstance(n, (ast.Name, ast.Attribute))}
                    hit = named & (set(classes) | specs)
                    if hit == {"Domain"}:  # a domain or not (a raw matrix): not a kind
                        out[NOT_KIND].append(site(mod, node))
                    elif hit:
                        out["isinstance checks"].append(site(mod, node))
                elif (fn in ("hasattr", "getattr") and len(args) >= 2
                      and isinstance(args[1], ast.Constant) and args[1].value in partial
                      and (fn == "hasattr" or len(args) == 3)):
                    probe = f"{site(mod, node)} ({args[1].value})"
                    if isinstance(args[0], ast.Name) and args[0].id in REQUEST_NAMES:
                        out[REQUEST_PROBES].append(probe)  # a request's field, not a domain's
                    else:
                        out["hasattr/getattr probes"].append(probe)
    return out


# -- names: route, algorithm, solver -------------------------------------------------------


def named_sites(mods: dict[str, Module], pattern: re.Pattern) -> list[tuple[str, str, str]]:
    """``(site, name, annotation and default as source)`` of every parameter and class
    field whose name matches ``pattern``."""
    out = []
    for mod in mods.values():
        src = mod.path.read_text()
        for node in ast.walk(mod.tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                args = node.args
                positional = args.posonlyargs + args.args
                defaults = [None] * (len(positional) - len(args.defaults)) + args.defaults
                pairs = list(zip(positional, defaults, strict=True))
                pairs += list(zip(args.kwonlyargs, args.kw_defaults, strict=True))
                for arg, default in pairs:
                    if pattern.match(arg.arg):
                        text = " = ".join(ast.get_source_segment(src, n) or ""
                                          for n in (arg.annotation, default) if n is not None)
                        out.append((site(mod, arg), arg.arg, text))
            elif isinstance(node, ast.ClassDef):
                for item in node.body:
                    if (isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name)
                            and pattern.match(item.target.id)):
                        text = ast.get_source_segment(src, item) or ""
                        out.append((site(mod, item), item.target.id, text))
    return out


# What a ``route`` site names, by where it stands (first match; read from the tree of
# issue 41: after the redesign every site left should be an HTTP one)
ROUTE_MEANINGS = (
    # the idempotency fingerprint's ``route`` is the request's HTTP route too ("POST
    # <operation> on <domain>", "POST /v1/domains"), hashed with its body
    ("HTTP route", lambda where, name, text: where.startswith(("service/api/",
                                                               "service/idempotency.py"))
     or (where.startswith("service/operations/base.py") and "bool" in text)),
    ("landmark descriptor", lambda where, name, _: name == "landmark_route"
     or where.startswith("solvers/softmaps/descriptors.py")),
    ("Dirichlet energy", lambda where, name, _: name == "dirichlet_route"
     or where.startswith("solvers/softmaps/energies.py")),
    ("pointwise green/solve", lambda where, *_: where.startswith("solvers/emd/pointwise.py")),
    ("geodesic mmp/edge-flip", lambda where, *_: where.startswith("solvers/geodesics.py")),
    ("histogram model", lambda where, *_: where.startswith(
        ("solvers/histograms/", "service/operations/histograms.py"))),
    ("hemisphere kernel", lambda where, *_: where.startswith(
        ("solvers/convolutional/hemisphere.py", "service/operations/applications.py"))),
    ("W2 method", lambda where, *_: where.startswith(
        ("solvers/convolutional/", "solvers/transport/", "service/operations/transport.py",
         "service/operations/matrices.py"))),
)


def route_meanings(mods: dict[str, Module]) -> dict[str, list[str]]:
    """``meaning -> sites`` of every ``route`` parameter and field (meaning "other" where
    :data:`ROUTE_MEANINGS` does not say), each site with the string values written there."""
    groups = defaultdict(list)
    for where, name, text in named_sites(mods, ROUTE_NAME):
        meaning = next((m for m, test in ROUTE_MEANINGS if test(where, name, text)), "other")
        values = sorted(set(re.findall(r"""["']([\w+-]+)["']""", text)))
        groups[meaning].append(f"{where} {name} {{{', '.join(values)}}}")
    return groups


# -- functions -----------------------------------------------------------------------------


def functions(mods: dict[str, Module]):
    """``(module, node, public)`` of every function and method."""
    for mod in mods.values():
        stack = [(mod.tree, True)]
        while stack:
            parent, public = stack.pop()
            for node in ast.iter_child_nodes(parent):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    pub = public and not node.name.startswith("_")
                    yield mod, node, pub
                    stack.append((node, False))  # nested functions are not public
                elif isinstance(node, ast.ClassDef):
                    stack.append((node, public and not node.name.startswith("_")))
                else:
                    stack.append((node, public))


def parameter_count(node) -> int:
    args = node.args
    names = [a.arg for a in args.posonlyargs + args.args + args.kwonlyargs]
    return len([n for n in names if n not in ("self", "cls")])


def body_lines(node) -> int:
    """A function's lines without its docstring: the numpydoc sections every public solver
    carries (issue 41, item 6) document it; they do not make it longer to read."""
    lines = node.end_lineno - node.lineno + 1
    first = node.body[0] if node.body else None
    if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
            and isinstance(first.value.value, str)):
        lines -= first.end_lineno - first.lineno + 1
    return lines


def long_and_wide(mods):
    long, wide = [], []
    for mod, node, public in functions(mods):
        lines = body_lines(node)
        if lines > MAX_LINES:
            long.append((lines, f"{site(mod, node)} {node.name}"))
        if public and parameter_count(node) > MAX_PARAMS:
            wide.append((parameter_count(node), f"{site(mod, node)} {node.name}"))
    return sorted(long, reverse=True), sorted(wide, reverse=True)


# -- import cycles -------------------------------------------------------------------------


def _type_checking_nodes(tree: ast.Module) -> set[int]:
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.dump(node.test):
            skip.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return skip


def import_edges(mods: dict[str, Module], local: bool, packages: bool = False
                 ) -> dict[str, set[str]]:
    """``module -> modules it imports`` (of this tree); ``local``: function bodies too;
    ``packages``: also the packages whose ``__init__`` the import runs first (``import
    a.b.c`` runs ``a`` and ``a.b``), but the importer's own."""
    edges = defaultdict(set)
    for mod in mods.values():
        skip = _type_checking_nodes(mod.tree)
        nodes = ast.walk(mod.tree) if local else _module_level(mod.tree)
        for node in nodes:
            if id(node) in skip:
                continue
            for target in _targets(mod, node, mods):
                parts = target.split(".")
                runs = [".".join(parts[:i]) for i in range(1, len(parts))] if packages else []
                for t in [target, *runs]:
                    if t != mod.name and t in mods and not mod.name.startswith(t + "."):
                        edges[mod.name].add(t)
    return edges


def _module_level(tree: ast.Module):
    """Statements run at import: the module body, into if/try/with blocks, not into
    functions or classes' methods."""
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            stack.extend(c for c in ast.iter_child_nodes(node) if isinstance(c, ast.stmt))


def _targets(mod: Module, node, mods) -> list[str]:
    if isinstance(node, ast.Import):
        return [_existing(a.name, mods) for a in node.names if _existing(a.name, mods)]
    if not isinstance(node, ast.ImportFrom):
        return []
    base = node.module or ""
    if node.level:
        package = mod.name.split(".")
        if mod.path.name != "__init__.py":
            package = package[:-1]
        package = package[:len(package) - node.level + 1]
        base = ".".join(package + ([node.module] if node.module else []))
    out = []
    for alias in node.names:
        target = _existing(f"{base}.{alias.name}", mods) or _existing(base, mods)
        if target:
            out.append(target)
    return out


def _existing(name: str, mods) -> str | None:
    return name if name in mods else None


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one member (Tarjan), largest first."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(set(edges) | {w for ws in edges.values() for w in ws}):
        if v not in index:
            visit(v)
    return sorted(out, key=lambda c: (-len(c), c))


def package_edges(edges: dict[str, set[str]], mods) -> dict[str, set[str]]:
    """The import graph between subpackages (``solvers.emd``; a top-level module stands for
    itself)."""
    def package(name):
        parts = name.split(".")
        return ".".join(parts[:2]) if len(parts) > 2 or (
            len(parts) == 2 and mods[name].path.name == "__init__.py") else name

    out = defaultdict(set)
    for src, targets in edges.items():
        for t in targets:
            if package(src) != package(t):
                out[package(src)].add(package(t))
    return out


# -- duplicates ----------------------------------------------------------------------------


def duplicate_pairs(folder: str) -> str:
    exe = shutil.which("duplicates")
    if exe is None:
        return "n/a (no duplicates command)"
    proc = subprocess.run([exe, "--repo", str(REPO / folder), "--most", "1", "--seconds",
                           "120"], capture_output=True, text=True, timeout=300)
    first = proc.stdout.splitlines()[0] if proc.stdout else proc.stderr.strip()
    found = re.match(r"(\d+) pairs", first)
    return found.group(1) if found else first


# -- report --------------------------------------------------------------------------------


def main(argv=None) -> None:
    global REPO
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--summary", action="store_true", help="the figures only")
    parser.add_argument("--repo", type=Path, default=REPO, help="the checkout to read "
                        "(default: this one)")
    args = parser.parse_args(argv)
    REPO = args.repo.resolve()
    mods = load_modules()
    kinds = kind_branches(mods)
    routes = route_meanings(mods)
    other = {m: v for m, v in routes.items() if m != "HTTP route"}
    methods = named_sites(mods, METHOD_NAMES)
    long, wide = long_and_wide(mods)
    wide_all = sum(parameter_count(n) > MAX_PARAMS for _, n, _ in functions(mods))
    top, every = import_edges(mods, local=False), import_edges(mods, local=True)
    cyc_top, cyc_all = cycles(top), cycles(every)
    cyc_init = cycles(import_edges(mods, local=False, packages=True))
    cyc_pkg_top, cyc_pkg = cycles(package_edges(top, mods)), cycles(package_edges(every, mods))
    method_counts = defaultdict(int)
    for _, name, _ in methods:
        method_counts[name] += 1
    figures = [
        ("kind branches outside solvers/domains/",
         f"{len(kinds['string comparisons']) + len(kinds['isinstance checks'])} "
         f"({len(kinds['string comparisons'])} string comparisons, "
         f"{len(kinds['isinstance checks'])} isinstance), plus "
         f"{len(kinds['hasattr/getattr probes'])} hasattr/getattr probes "
         f"(not counted: {len(kinds[NOT_KIND])} isinstance against the base Domain, "
         f"{len(kinds[REQUEST_PROBES])} probes of a request's fields)"),
        ("`route` sites not naming an HTTP route",
         f"{sum(map(len, other.values()))} with {len(other)} meanings "
         f"({sum(map(len, routes.values()))} sites, {len(routes)} meanings with HTTP)"),
        ("`algorithm`/`solver` parameters and fields",
         ", ".join(f"{n} {c}" for n, c in sorted(method_counts.items())) or "0"),
        (f"functions over {MAX_LINES} lines", str(len(long))),
        (f"public functions over {MAX_PARAMS} parameters", f"{len(wide)} (all functions: "
         f"{wide_all})"),
        ("import cycles (module-level imports)", _cycle_line(cyc_top)),
        ("import cycles (module-level imports, package __init__s they run)",
         _cycle_line(cyc_init)),
        ("import cycles (function-local imports too)", _cycle_line(cyc_all)),
        ("package cycles (module-level imports)", _cycle_line(cyc_pkg_top)),
        ("package cycles (function-local imports too)", _cycle_line(cyc_pkg)),
        ("duplicates pairs in solvers/", duplicate_pairs("solvers")),
        ("duplicates pairs in service/", duplicate_pairs("service")),
    ]
    print("| figure | value |\n|---|---|")
    for name, value in figures:
        print(f"| {name} | {value} |")
    if args.summary:
        return
    _details(kinds, routes, methods, long, wide,
             {"module-level imports": cyc_top, "module-level imports and the package "
              "__init__s they run": cyc_init, "function-local too": cyc_all,
              "packages, module-level imports": cyc_pkg_top,
              "packages, function-local too": cyc_pkg})


def _cycle_line(comps: list[list[str]]) -> str:
    return f"{len(comps)} (sizes {', '.join(str(len(c)) for c in comps) or '-'})"


def _details(kinds, routes, methods, long, wide, cycle_sets: dict) -> None:
    for kind, sites in sorted(kinds.items()):
        sites = sorted(sites, key=lambda s: (s.split(":")[0], int(s.split(":")[1].split()[0])))
        print(f"\n## {kind} ({len(sites)})\n" + "\n".join(f"- {s}" for s in sites))
    print(f"\n## route sites by meaning ({len(routes)} meanings)")
    for meaning, sites in sorted(routes.items()):
        print(f"- {meaning} ({len(sites)}): " + "; ".join(sites))
    print(f"\n## algorithm/solver sites ({len(methods)})")
    print("\n".join(f"- {where} {name}: {' '.join(text.split())[:90]}"
                    for where, name, text in methods))
    print(f"\n## functions over {MAX_LINES} lines ({len(long)})")
    print("\n".join(f"- {n} lines: {s}" for n, s in long))
    print(f"\n## public functions over {MAX_PARAMS} parameters ({len(wide)})")
    print("\n".join(f"- {n}: {s}" for n, s in wide))
    for title, comps in cycle_sets.items():
        print(f"\n## import cycles, {title} ({len(comps)})")
        print("\n".join(f"- {' ↔ '.join(c)}" for c in comps))


if __name__ == "__main__":
    main()
