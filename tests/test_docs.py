"""The documentation's generated pages cover the code: every public name of every
``solvers`` package is in the API reference, every route of the service in the service
guide, every setting in the settings table (docs/_ext/otgeo_docs.py writes them)."""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path

import solvers
from service.settings import Settings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs" / "_ext"))
import otgeo_docs  # noqa: E402


def _public_modules():
    """Every solvers module or package that declares ``__all__`` (its public API)."""
    yield solvers
    for info in pkgutil.walk_packages(solvers.__path__, "solvers."):
        if info.name.rsplit(".", 1)[-1].startswith("_"):
            continue
        module = importlib.import_module(info.name)
        if hasattr(module, "__all__"):
            yield module


def test_every_public_name_of_solvers_is_in_the_api_reference():
    page = otgeo_docs.api_reference()
    documented = set()  # the objects the reference documents, under any package
    for package, _ in otgeo_docs.PACKAGES:
        module = importlib.import_module(package)
        for name in otgeo_docs.public_names(package):
            assert f"   {name}" in page.splitlines(), f"{package}.{name}"
            documented.add(id(getattr(module, name)))
    missing = [f"{module.__name__}.{name}" for module in _public_modules()
               for name in module.__all__ if id(getattr(module, name)) not in documented]
    assert not missing, f"not in the API reference (docs/_ext/otgeo_docs.py PACKAGES): {missing}"


def test_every_service_route_is_in_the_service_guide():
    import json

    from service.cli import openapi_document

    table = otgeo_docs.routes_table()
    spec = json.loads(openapi_document())
    for path, methods in spec["paths"].items():
        for method, op in methods.items():
            assert f"``{method.upper()} {path}``" in table
            assert f"``{op['operationId']}``" in table


def test_every_setting_is_in_the_settings_table():
    table = otgeo_docs.settings_table()
    for name in Settings.model_fields:
        assert f"``OTGEO_{name.upper()}``" in table
