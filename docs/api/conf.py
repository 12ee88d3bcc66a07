"""Sphinx configuration of the API reference: `make docs` (warnings are errors, checked in CI)."""
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "src"))

import stiction  # noqa: E402  (the installed package, with its compiled core)
from stiction.scene_schema import reference_markdown  # noqa: E402

# The scene key reference is generated from the schema the loader enforces.
generated = HERE / "_generated"
generated.mkdir(exist_ok=True)
(generated / "scene-keys.md").write_text(reference_markdown() + "\n")

project = "stiction"
release = stiction.__version__
extensions = ["sphinx.ext.autodoc", "myst_parser"]  # plain-prose docstrings: no napoleon (it read "x: y" lines as types)
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build"]
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
# Boost.Python signatures in docstrings are not Python signatures
autodoc_docstring_signature = False
html_theme = "alabaster"
nitpicky = False
suppress_warnings = ["myst.header"]


def _plain_core_docstrings(app, what, name, obj, options, lines):
    """The compiled core's docstrings are plain text (Boost.Python), not reST: escape the
    characters reST would read as markup (|x| as a substitution, *x* as emphasis)."""
    module = getattr(obj, "__module__", "") or ""
    fget = obj.fget if isinstance(obj, property) else None
    if (module.startswith("stiction._core") or "Boost.Python" in repr(type(obj))
            or (fget is not None and "Boost.Python" in repr(type(fget)))):
        lines[:] = [line.replace("\\", "\\\\").replace("|", "\\|").replace("*", "\\*") for line in lines]


def setup(app):
    app.connect("autodoc-process-docstring", _plain_core_docstrings)
