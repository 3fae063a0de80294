"""The scratch folder of an out-of-core run: the matrix's columns on disk when they do not fit the budget.

When a binary matrix's column bitsets (:mod:`camplace.visibility.bits`) would take the run past its
memory budget (``--memory-budget-gb``, default half the RAM), the engine keeps them in a file of
this folder, mapped into memory (``MAP_SHARED``): each chunk writes its own columns and then drops
its pages from the process (``madvise(MADV_DONTNEED)``; the data stays in the file and the page
cache, which the kernel writes back and evicts under pressure), and the presolve reads the columns
back block by block the same way. The budget then bounds the run's resident memory, not the
instance size. A graded matrix quantised to bytes (:mod:`camplace.visibility.qbytes`) goes the same
way when even the solver's lean quality tree would not fit beside it: its columns in a file of
this folder, dropped chunk by chunk as they are cast; the solver's tree then reads them through
the page cache.

The folder is a fresh temporary folder (``.camplace-scratch-*``) beside the run's output folder,
or in ``--scratch DIR``; :class:`Scratch` removes it on success, on an error and on Ctrl-C (it is a
context manager; the run wraps all of its stages in it). Before a file is mapped its whole size is
reserved on disk (``posix_fallocate``), so a full disk is a one-line error before the work (a
write into a mapped file on a full disk would otherwise kill the process with SIGBUS), and so is a
folder that cannot be written.
"""

from __future__ import annotations

import mmap
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from camplace.errors import CamplaceError

__all__ = ["Scratch", "release_pages"]

_PAGE = mmap.PAGESIZE
#: the file mappings made by :meth:`Scratch.array` (id -> mapping): the only ones
#: :func:`release_pages` drops pages of (dropping those of an anonymous private mapping, such as
#: :func:`camplace.visibility.store.populated_empty`'s, would zero its data)
_SHARED: dict[int, mmap.mmap] = {}


class Scratch:
    """A lazily created temporary folder for out-of-core files (see the module docstring).

    Parameters
    ----------
    parent : path or None
        Where the folder is made (``--scratch DIR``, else the output folder's parent; None: the
        system's temporary folder).
    """

    def __init__(self, parent: str | Path | None = None):
        self.parent = Path(parent) if parent is not None else Path(tempfile.gettempdir())
        self.path: Path | None = None
        self._maps: list[mmap.mmap] = []

    def __enter__(self) -> "Scratch":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _folder(self) -> Path:
        if self.path is None:
            try:
                self.parent.mkdir(parents=True, exist_ok=True)
                self.path = Path(tempfile.mkdtemp(prefix=".camplace-scratch-", dir=self.parent))
            except OSError as exc:
                raise CamplaceError(f"scratch folder {self.parent}: cannot write there ({exc.strerror or exc}); "
                                    "give a writable folder with --scratch DIR") from None
        return self.path

    def array(self, name: str, shape: tuple[int, ...], dtype=np.uint64) -> np.ndarray:
        """A zeroed array of ``shape`` backed by a file ``name`` of the folder, its space reserved.

        Raises
        ------
        CamplaceError
            One line when the folder cannot be written or lacks the space (exit 2).
        """
        dtype = np.dtype(dtype)
        nbytes = int(np.prod(shape)) * dtype.itemsize
        folder = self._folder()
        path = folder / name
        try:
            free = shutil.disk_usage(folder).free
            if nbytes > free:
                raise OSError(28, "No space left on device")
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                if nbytes:
                    os.posix_fallocate(fd, 0, nbytes)
                buf = mmap.mmap(fd, max(nbytes, 1), flags=mmap.MAP_SHARED, prot=mmap.PROT_READ | mmap.PROT_WRITE)
            finally:
                os.close(fd)
        except OSError as exc:
            self.close()
            raise CamplaceError(f"scratch folder {folder.parent}: cannot hold the {nbytes / 2**30:.2f} GiB of the matrix "
                                f"columns ({exc.strerror or exc}); free space there or give another folder with "
                                "--scratch DIR, or raise --memory-budget-gb") from None
        self._maps.append(buf)
        _SHARED[id(buf)] = buf
        return np.frombuffer(buf, dtype=dtype, count=int(np.prod(shape))).reshape(shape)

    def close(self) -> None:
        """Remove the folder and everything in it (mapped arrays stay readable until dropped)."""
        for buf in self._maps:
            _SHARED.pop(id(buf), None)
        self._maps = []
        if self.path is not None:
            shutil.rmtree(self.path, ignore_errors=True)
            self.path = None


def mapping_of(array: np.ndarray) -> mmap.mmap | None:
    """The memory mapping an array was made on (``np.frombuffer`` of an ``mmap``: a scratch file's
    array, :func:`camplace.visibility.store.first_touch_empty`'s), None for any other array.
    numpy 2 keeps a ``memoryview`` of the buffer as the array's base, so the chain of bases is
    followed through it."""
    base = array.base
    while base is not None and not isinstance(base, mmap.mmap):
        base = base.obj if isinstance(base, memoryview) else getattr(base, "base", None)
    return base


def release_pages(array: np.ndarray, lo: int, hi: int) -> None:
    """Drop the pages of bytes ``lo:hi`` of a file-backed array from this process's memory
    (``MADV_DONTNEED``; its data stays in the file). A no-op for any array that is not a
    :meth:`Scratch.array` (anonymous memory would lose its data)."""
    base = mapping_of(array)
    if base is None or _SHARED.get(id(base)) is not base or not hasattr(base, "madvise"):
        return
    a = (lo + _PAGE - 1) // _PAGE * _PAGE
    b = hi // _PAGE * _PAGE
    if b > a:
        try:
            # offsets within the mapping: the array starts at its beginning
            base.madvise(mmap.MADV_DONTNEED, a, b - a)
        except (OSError, ValueError):
            pass
