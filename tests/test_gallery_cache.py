"""The gallery's result cache (examples/gallery/_cache.py): a hit only when the example, its
inputs and every library module it loaded are unchanged."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples" / "gallery"))
import _cache  # noqa: E402


@pytest.fixture
def setup(tmp_path, monkeypatch):
    monkeypatch.setattr(_cache, "CACHE", tmp_path / "cache")
    monkeypatch.delenv("OTGEO_GALLERY_CACHE", raising=False)
    package = tmp_path / "pkg" / "fakelib"  # a stand-in for solvers, tracked as a dependency
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "core.py").write_text("FACTOR = 2.0\n")
    monkeypatch.syspath_prepend(str(tmp_path / "pkg"))
    example = tmp_path / "plot_example.py"
    example.write_text("# an example\n")
    data = tmp_path / "input.txt"
    data.write_text("1 2 3\n")
    calls = []

    def compute():
        core = importlib.import_module("fakelib.core")
        calls.append(1)
        return {"values": np.arange(4) * core.FACTOR, "count": len(calls)}

    def run(inputs=(data, 3)):
        return _cache.cached(compute, inputs, example=example, packages=("fakelib",))

    yield run, calls, example, data, package
    for name in ("fakelib.core", "fakelib"):
        sys.modules.pop(name, None)


def test_unchanged_example_loads_the_stored_arrays(setup):
    run, calls, *_ = setup
    first = run()
    second = run()
    assert len(calls) == 1
    np.testing.assert_array_equal(first["values"], second["values"])
    assert int(second["count"]) == 1


def test_a_changed_example_source_recomputes(setup):
    run, calls, example, *_ = setup
    run()
    example.write_text("# an example, edited\n")
    run()
    assert len(calls) == 2


def test_changed_inputs_recompute(setup):
    run, calls, _, data, _ = setup
    run()
    run(inputs=(data, 4))  # a parameter
    assert len(calls) == 2
    data.write_text("1 2 4\n")  # a file's content
    run(inputs=(data, 4))
    assert len(calls) == 3
    run(inputs=(data, 4))
    assert len(calls) == 3


def test_a_changed_library_module_recomputes(setup):
    run, calls, _, _, package = setup
    run()
    meta_deps = _cache.loaded_modules(("fakelib",))
    assert "fakelib/core.py" in meta_deps  # named inside its package, wherever imported from
    (package / "core.py").write_text("FACTOR = 3.0\n")
    run()
    assert len(calls) == 2


def test_the_example_defaults_to_the_calling_file(tmp_path, monkeypatch):
    monkeypatch.setattr(_cache, "CACHE", tmp_path / "cache")
    _cache.cached(lambda: {"x": np.zeros(2)})
    assert (tmp_path / "cache" / f"{Path(__file__).stem}.npz").exists()


def test_the_cache_can_be_switched_off(setup, monkeypatch):
    run, calls, *_ = setup
    run()
    monkeypatch.setenv("OTGEO_GALLERY_CACHE", "off")
    run()
    run()
    assert len(calls) == 3
