"""pyproject.toml installs without setuptools' deprecation warnings: ``project.license`` is
an SPDX expression (a TOML table makes ``pip install -e .`` warn "`project.license` as a TOML
table is deprecated", once per build step), and the build requires a setuptools that reads
it (77.0, PEP 639)."""

from __future__ import annotations

import tomllib

from doc_examples import ROOT
from packaging.requirements import Requirement
from packaging.version import Version

SPDX_SETUPTOOLS = Version("77.0")


def test_license_is_an_spdx_string_and_the_build_reads_it():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["project"]["license"] == "MIT"
    setuptools = [Requirement(r) for r in project["build-system"]["requires"]
                  if Requirement(r).name == "setuptools"]
    assert len(setuptools) == 1, project["build-system"]
    spec = setuptools[0].specifier
    assert spec, "setuptools needs a lower bound"
    assert not spec.contains(Version("76.9")) and spec.contains(SPDX_SETUPTOOLS), spec
