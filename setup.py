"""Build hook: compile the numba kernels into the wheel (see tools/jit_cache.py).

Everything else about the package is declared in pyproject.toml.
"""

import os
import subprocess
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py


class BuildPyWithKernels(build_py):
    """``build_py``, then compile the recorded kernel signatures inside the build folder."""

    def run(self) -> None:
        super().run()
        if self.editable_mode:
            return  # an editable install compiles beside the sources on first use
        package = Path(self.build_lib).resolve() / "camplace"
        for stale in [*package.rglob("*.nbi"), *package.rglob("*.nbc")]:  # left by an earlier build in build/
            stale.unlink()
        tool = Path(__file__).resolve().parent / "tools" / "jit_cache.py"
        if tool.is_file() and not os.environ.get("CAMPLACE_NO_PRECOMPILE"):
            subprocess.run([sys.executable, str(tool), "build", str(package.parent)], check=False)


setup(cmdclass={"build_py": BuildPyWithKernels})
