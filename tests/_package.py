"""The camplace that a test's subprocesses run: the one this test process imported.

In a development checkout that is ``src/`` (an editable install); in CI it is the package that
``pip install .`` put in the environment, with the kernels it compiled at install time. A
subprocess pointed at the checkout's ``src/`` instead would test other files than the ones the
user installs and compile every kernel it meets again (about 64 kernels in a CI run).
"""

from __future__ import annotations

import os
import site
from pathlib import Path

import camplace

#: the folder that holds the imported ``camplace`` package
PACKAGE_PARENT = str(Path(camplace.__file__).resolve().parents[1])
_SITE_DIRS = {str(Path(p).resolve()) for p in [*site.getsitepackages(), site.getusersitepackages()]}


def subprocess_env(base: dict[str, str] | None = None, **extra: str) -> dict[str, str]:
    """``base`` (default: this process's environment) where ``python -m camplace`` runs the imported camplace.

    An installed camplace (in a site-packages folder) is found by the interpreter itself, after any
    folder on ``base``'s PYTHONPATH (a test may put a stand-in module there); otherwise (``src/``)
    its folder goes first on PYTHONPATH.

    Parameters
    ----------
    base : dict of str to str, optional
        The environment to start from.
    **extra : str
        Variables to set on top.

    Returns
    -------
    dict of str to str
        A new environment for ``subprocess``.
    """
    env = dict(os.environ if base is None else base)
    if PACKAGE_PARENT not in _SITE_DIRS:  # installed: the interpreter finds it there, after PYTHONPATH
        env["PYTHONPATH"] = PACKAGE_PARENT + os.pathsep + env.get("PYTHONPATH", "")
    env.update(extra)
    return env
