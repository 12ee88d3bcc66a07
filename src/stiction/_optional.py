"""Optional dependencies: a missing one is named together with the extra that installs it."""
from __future__ import annotations

import importlib
from types import ModuleType


class MissingExtraError(ImportError):
    """An optional package needed for this feature is not installed."""


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import `module` or raise MissingExtraError naming the extra of stiction that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtraError(f"{feature} needs the optional package {module!r}, which is not installed: "
                                f"pip install 'stiction[{extra}]'") from None
