"""Optional dependencies: the heavy parts not every run needs, imported only where used, with a clear
message naming the extra that installs them.

=========  ================  ===========================================================
extra      package           what needs it
=========  ================  ===========================================================
unwrap     xatlas            ``--uv unwrap`` / meshes without UVs: charts for the curved
                             leftovers (without it they keep planar charts, with a warning)
view       plotly            the 3D views: ``scantex view`` and the report's 3D section
                             (the report is written without it, saying so)
bench      scikit-image      the classical inpainting baseline in ``bench/``
usd        usd-core          USD scans (``.usdz``, ``.usda``, ``.usdc``) in, ``enhanced.usdz`` out:
                             Pixar's library
=========  ================  ===========================================================
"""

from __future__ import annotations

import importlib
import importlib.util
import sys

#: module -> (pip package, scantex extra)
OPTIONAL = {"xatlas": ("xatlas", "unwrap"), "plotly": ("plotly", "view"), "skimage": ("scikit-image", "bench"),
            "pxr": ("usd-core", "usd")}


class MissingDependency(ImportError):
    """An optional package that a feature needs is not installed; the message says how to install it."""


def has_module(name: str) -> bool:
    """Whether ``name`` can be imported, without importing it."""
    if name in sys.modules:
        return sys.modules[name] is not None  # None: import blocked (also how the tests hide a package)
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def install_hint(name: str) -> str:
    """``pip install 'scantex[EXTRA]'`` (or the plain package) for module ``name``."""
    package, extra = OPTIONAL.get(name, (name, None))
    return f"pip install 'scantex[{extra}]'" if extra else f"pip install {package}"


def missing_message(name: str, feature: str) -> str:
    package, _ = OPTIONAL.get(name, (name, None))
    return f"{feature} needs the Python package {package}, which is not installed: {install_hint(name)}"


def require(name: str, feature: str):
    """Import and return module ``name``, or raise :class:`MissingDependency` with a one-line message
    naming ``feature`` and the ``pip install`` that provides it."""
    try:
        return importlib.import_module(name)
    except ImportError as error:
        if error.name is not None and error.name.split(".")[0] != name.split(".")[0]:
            raise  # the package is there but broken: its own error says more
        raise MissingDependency(missing_message(name.split(".")[0], feature)) from error
