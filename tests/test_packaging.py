"""What a pip-installed package needs: the build requirements CMake asks for, the package data
the wheel ships, the stubs and py.typed. (The wheel itself is built, installed into a fresh venv
and used from /tmp by .ci/wheel-smoke, run in CI.)"""
import re
import tomllib
from pathlib import Path

import stiction
from stiction import resources
from stiction._stubgen import generate, stub_path

ROOT = Path(__file__).resolve().parents[1]


def test_every_cmeel_library_cmake_needs_is_a_build_requirement():
    """`pip install .` builds in isolation from [build-system].requires only: the cmeel
    packages of requirements.txt (C++ headers found by CMake) must all be there."""
    requires = tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]["requires"]
    names = {re.split(r"[<>=!~ ]", r)[0] for r in requires}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        name = re.split(r"[<>=!~ ]", line.strip())[0]
        if name.startswith("cmeel") or name in ("pin", "eigenpy", "proxsuite"):
            assert name in names, f"{name} is in requirements.txt but not in [build-system].requires"


def test_the_wheel_ships_the_demo_problems_the_demo_solves():
    cmake = (ROOT / "CMakeLists.txt").read_text()
    shipped = re.findall(r"benchmarks/fclib/(\S+)", cmake)
    assert sorted(shipped) == sorted(resources.DEMO_FCLIB_PROBLEMS)
    for name in shipped:
        assert (resources.fclib_dir() / name).is_file()
    assert "install(DIRECTORY robots/ DESTINATION stiction/data/robots)" in cmake


def test_bundled_data_is_found():
    assert (resources.scenes_dir() / "solo12-stand.toml").is_file()
    assert (resources.robots_dir() / "cube.urdf").is_file()


def test_stubs_match_the_compiled_module():
    """_core.pyi is generated from the module's docstrings; regenerate with
    `python -m stiction._stubgen` after changing the bindings."""
    assert stub_path().read_text() == generate(), "src/stiction/_core.pyi is stale: python -m stiction._stubgen"
    assert (Path(stiction.__file__).parent / "py.typed").is_file()


def test_optional_extras_are_named_when_missing(monkeypatch):
    import sys

    import pytest

    from stiction._optional import MissingExtraError, require

    monkeypatch.setitem(sys.modules, "meshcat", None)  # import meshcat now raises ImportError
    with pytest.raises(MissingExtraError, match=r"pip install 'stiction\[record\]'"):
        require("meshcat", "record", "recordings")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert {"record", "plot", "bench", "test", "docs"} <= set(extras)
