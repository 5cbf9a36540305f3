"""Packaging metadata: licence, one version source, typing marker, ``--version``."""
from __future__ import annotations

import pathlib
import tomllib

import pytest

import sionna_mmir
from sionna_mmir.cli.main import main

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def project() -> dict:
    with open(ROOT / "pyproject.toml", "rb") as f:
        return tomllib.load(f)


def test_01_license_is_an_spdx_expression_with_its_text(project):
    meta = project["project"]
    assert meta["license"] == "Apache-2.0"                  # PEP 639: a string, no table
    assert meta["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text
    assert not any(c.startswith("License ::") for c in meta.get("classifiers", []))
    assert int(project["build-system"]["requires"][0].split(">=")[1]) >= 77


def test_02_one_version_source(project, capsys):
    assert "version" not in project["project"]
    assert "version" in project["project"]["dynamic"]
    attr = project["tool"]["setuptools"]["dynamic"]["version"]["attr"]
    assert attr == "sionna_mmir.__version__"
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"sionna-mmir {sionna_mmir.__version__}"


def test_03_typed_marker_is_package_data(project):
    assert (ROOT / "sionna_mmir" / "py.typed").is_file()
    assert "py.typed" in project["tool"]["setuptools"]["package-data"]["sionna_mmir"]
