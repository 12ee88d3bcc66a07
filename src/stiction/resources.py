"""Where the bundled data lives: scenes, URDFs and the small FCLib demo set.

An installed wheel carries them as package data under ``stiction/data/`` (CMake installs
``robots/`` and the demo problems of ``benchmarks/fclib/`` there) and they are found with
``importlib.resources``. Imported from a source checkout (an editable install), the package reads
the checkout itself (``robots/``, ``benchmarks/fclib/``), which is always current and also holds
the whole FCLib set.
"""
from __future__ import annotations

import importlib.resources
from pathlib import Path

# The FCLib problems shipped in the wheel (the ones `stiction demo` solves).
DEMO_FCLIB_PROBLEMS = (
    "Toy--FrictionContact3D_RR_1c.dat",
    "Rover--Rover1039.dat",
    "OneObject--OneObject-i1028-138.hdf5.dat",
    "BoxesStack--BoxesStack1-i100000-32.hdf5.dat",
    "PerioBox--LMGC_100_PR_PerioBox-i00361-60-03000.hdf5",
    "Confeti--Confeti-ex13-Fc3D-SBM.dat",
)


def _package_data() -> Path | None:
    data = importlib.resources.files("stiction") / "data"
    return Path(str(data)) if data.is_dir() else None


def _source_root() -> Path | None:
    root = Path(__file__).resolve().parents[2]
    return root if (root / "robots" / "scenes").is_dir() and (root / "pyproject.toml").is_file() else None


def _find(installed: str, source: str, what: str) -> Path:
    # Running from a source checkout (an editable install): its own files, always current (the
    # copy an editable build also installs under stiction/data would miss files added since).
    root = _source_root()
    if root is not None and (root / source).is_dir():
        return root / source
    data = _package_data()
    if data is not None and (data / installed).is_dir():
        return data / installed
    raise FileNotFoundError(f"the bundled {what} are missing: neither stiction/data/{installed} (an installed "
                            f"wheel) nor {source}/ of a source checkout was found; reinstall stiction")


def robots_dir() -> Path:
    """The bundled URDFs (cube, ball, rod) and their meshes."""
    return _find("robots", "robots", "URDF files")


def scenes_dir() -> Path:
    """The bundled scene files (``*.toml``)."""
    return _find("robots/scenes", "robots/scenes", "scene files")


def fclib_dir() -> Path:
    """The FCLib problems: the demo set in a wheel, the whole set in a source checkout."""
    return _find("fclib", "benchmarks/fclib", "FCLib problems")
