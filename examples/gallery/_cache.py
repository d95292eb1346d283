"""A result cache for heavy gallery examples: an unchanged example does not recompute.

``cached(compute, inputs)``, called from an example, returns the dict of arrays that
``compute()`` returns, from ``docs/_gallery_cache/<example>.npz`` when that file was written

* from the same example source (the whole file: any edit reruns it),
* with the same ``inputs`` (files are hashed by content, arrays by bytes, the rest by
  ``repr``) and the same numpy/scipy versions,
* while every ``solvers`` module that was loaded when it was computed still has the same
  content (the modules are recorded with their hashes: a change elsewhere in the library
  does not invalidate it, a change in any module it could have used does).

Otherwise it calls ``compute()`` and rewrites the file. The cache files are *committed*:
the CI builds the docs from a clean clone, so only a committed result can spare it a
recomputation, while any changed example or dependency still misses and reruns there. A
stale file costs one recomputation and nothing else (it is overwritten, one file per
example). ``OTGEO_GALLERY_CACHE=off`` recomputes everything (and rewrites nothing);
``OTGEO_GALLERY_CACHE_DIR`` moves the directory.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
CACHE = Path(os.environ.get("OTGEO_GALLERY_CACHE_DIR", ROOT / "docs" / "_gallery_cache"))
PACKAGES = ("solvers",)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def input_digest(inputs: Iterable) -> str:
    """One hash over ``inputs``: paths by file content, arrays by dtype/shape/bytes, the rest
    by ``repr`` (numbers, strings, dicts of them)."""
    h = hashlib.sha256()
    for item in inputs:
        if isinstance(item, Path):
            h.update(b"file:" + _sha(item.read_bytes()).encode())
        elif isinstance(item, np.ndarray):
            a = np.ascontiguousarray(item)
            h.update(f"array:{a.dtype}:{a.shape}:".encode() + a.tobytes())
        else:
            h.update(b"value:" + repr(item).encode())
    return h.hexdigest()


def _package_dir(package: str) -> Path | None:
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(list(spec.submodule_search_locations)[0]).resolve().parent


def loaded_modules(packages: Iterable[str] = PACKAGES) -> dict[str, str]:
    """``{"package/.../module.py": sha256}`` of every loaded module of ``packages`` (the
    dependencies of a result computed in this process; a superset when other work ran
    before), named relative to the directory the package is imported from."""
    out = {}
    for name, module in list(sys.modules.items()):
        package = name.split(".")[0]
        path = getattr(module, "__file__", None)
        if package not in packages or not path or not os.path.exists(path):
            continue
        base = _package_dir(package)
        if base is not None:
            out[Path(path).resolve().relative_to(base).as_posix()] = _sha(Path(path).read_bytes())
    return out


def _fresh(deps: dict[str, str]) -> bool:
    """Every recorded module, found where its package is imported from now, unchanged."""
    for rel, digest in deps.items():
        base = _package_dir(rel.split("/")[0])
        path = None if base is None else base / rel
        if path is None or not path.exists() or _sha(path.read_bytes()) != digest:
            return False
    return True


def key_of(example: str | Path, inputs: Iterable) -> str:
    import scipy

    source = Path(example).read_bytes()
    return _sha(b"|".join([_sha(source).encode(), input_digest(inputs).encode(),
                           np.__version__.encode(), scipy.__version__.encode()]))


def cached(compute: Callable[[], dict], inputs: Iterable = (), *,
           example: str | Path | None = None,
           packages: Iterable[str] = PACKAGES) -> dict[str, np.ndarray]:
    """``compute()``'s dict of arrays (or numbers), from the cache when it is fresh (module
    docstring); prints whether it was loaded or computed, and the computation's time.

    ``example`` is the example's file, by default the caller's (sphinx-gallery defines no
    ``__file__`` but compiles each example under its own file name).
    """
    example = Path(example if example is not None else sys._getframe(1).f_code.co_filename)
    path = CACHE / f"{example.stem}.npz"
    key = key_of(example, list(inputs))
    enabled = os.environ.get("OTGEO_GALLERY_CACHE", "on").lower() not in ("off", "0", "no")
    if enabled and path.exists():
        with np.load(path, allow_pickle=False) as stored:
            meta = json.loads(str(stored["__meta__"]))
            if meta["key"] == key and _fresh(meta["deps"]):
                print(f"(results loaded from docs/_gallery_cache/{path.name}; computing them "
                      f"took {meta['seconds']:.1f} s)")
                return {k: stored[k] for k in stored.files if k != "__meta__"}
    start = time.perf_counter()
    result = {k: np.asarray(v) for k, v in compute().items()}
    seconds = time.perf_counter() - start
    print(f"(computed in {seconds:.1f} s)")
    if enabled:
        meta = {"key": key, "deps": loaded_modules(packages), "seconds": seconds}
        CACHE.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, __meta__=np.asarray(json.dumps(meta, sort_keys=True)),
                            **result)
        os.replace(tmp, path)
    return result
