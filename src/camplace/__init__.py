"""camplace: optimal placement of a small team of cameras to observe a dynamic event.

The small public API::

    import camplace
    inst = camplace.builtin("comet-67p-bunker")      # or camplace.load_instance("my.toml")
    sol = camplace.run(inst, seed=0, outdir="out")   # a Solution (status, objective, bound, gap, cameras)
    A = camplace.load_visibility("out")              # the points x candidates matrix (scipy CSR, float32)
    folder = camplace.RunFolder("out")               # every file of the folder, each read on first use
"""

from __future__ import annotations

from camplace._lazy import lazy_getattr
from camplace.errors import CamplaceError, InstanceError

# The rest is imported on first use, so that e.g. ``import camplace.solver`` pulls in no geometry.
_LAZY = {
    "Instance": "camplace.instance",
    "builtin": "camplace.instance",
    "load_instance": "camplace.instance",
    "save_instance": "camplace.instance",
    "RunFolder": "camplace.runfolder",
    "Solution": "camplace.solution",
    "run": "camplace.pipeline",
    "load_visibility": "camplace.visibility.store",
}


_lazy_attr = lazy_getattr(__name__, _LAZY)


def _version() -> str:
    """The installed distribution's version (importlib.metadata costs 0.1 s, so only on demand)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("camplace")
    except PackageNotFoundError:  # running from a source tree
        return "0.0.0+src"


def __getattr__(name: str):
    if name == "__version__":
        return _version()
    return _lazy_attr(name)

__all__ = [
    "CamplaceError",
    "Instance",
    "InstanceError",
    "RunFolder",
    "Solution",
    "__version__",
    "builtin",
    "load_instance",
    "load_visibility",
    "run",
    "save_instance",
]
