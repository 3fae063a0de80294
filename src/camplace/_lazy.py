"""Lazy package attributes: names resolved from their modules on first use (PEP 562)."""

from __future__ import annotations

import importlib
from typing import Any, Callable


def lazy_getattr(package: str, table: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that imports ``table[name]`` on first access to ``name``.

    Keeps heavy dependencies (OpenCV, Embree, matplotlib) out of ``import camplace.<package>``.
    """

    def __getattr__(name: str) -> Any:
        if name in table:
            return getattr(importlib.import_module(table[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__


def import_trimesh() -> Any:
    """``trimesh``, imported without its optional Embree ray interface.

    ``import trimesh`` loads ``embreex`` when it is installed (``trimesh.ray.ray_pyembree``), which
    costs a process that only reads meshes (a run folder's ``instance.toml``) the Embree library.
    camplace casts rays through :mod:`camplace.visibility.raycast`, never through ``trimesh.ray``,
    so the first import of trimesh here hides ``embreex`` from it (trimesh then falls back to its
    own ray module); ``embreex`` itself stays importable afterwards.
    """
    import sys

    if "trimesh" in sys.modules:
        return sys.modules["trimesh"]
    hide = "embreex" not in sys.modules
    if hide:
        sys.modules["embreex"] = None  # type: ignore[assignment]  # "import embreex" raises ImportError
    try:
        import trimesh
    finally:
        if hide and sys.modules.get("embreex", 0) is None:
            del sys.modules["embreex"]
    return trimesh
