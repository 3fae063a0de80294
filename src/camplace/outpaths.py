"""Output paths checked before a verb does any work.

Every verb that writes calls one of these on its output path first, so that a file where a folder
is needed (or the reverse) is a one-line :class:`~camplace.errors.CamplaceError` (exit code 2)
naming the path and the fix, before anything is computed or written. Imports nothing heavy.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

from camplace.errors import CamplaceError

__all__ = ["check_new_file", "check_out_file", "check_out_folder"]


def _check_parents(path: Path, option: str) -> None:
    """The nearest existing folder above ``path`` must be a folder (not a file)."""
    for parent in path.parents:
        if parent.exists() or parent.is_symlink():
            if not parent.is_dir():
                raise CamplaceError(f"{option}: {parent} is a file, so {path} cannot be created in it "
                                    f"(give a path outside {parent}, or move that file away)")
            return


def check_out_folder(path: str | Path, option: str = "-o/--out", *, files: Iterable[str] = (),
                     folders: Iterable[str] = ()) -> Path:
    """Check that ``path`` can be (or already is) an output folder.

    Parameters
    ----------
    path : path
        The folder the verb writes into (created later, when the verb writes).
    option : str
        The option that gave it, for the message (e.g. ``"-o/--out"``).
    files : iterable of str
        Names of files the verb writes in the folder: none may be a folder.
    folders : iterable of str
        Names of sub-folders the verb writes: none may be a file.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    CamplaceError
        When ``path`` (or a folder above it) is a file, or a named entry has the wrong kind.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise CamplaceError(f"{option}: {path} is a file, not a folder (give a folder name, or move the file away)")
    _check_parents(path, option)
    for name in files:
        if (path / name).is_dir():
            raise CamplaceError(f"{option}: {path / name} is a folder, but this verb writes a file there "
                                f"(move that folder away, or give another -o folder)")
    for name in folders:
        sub = path / name
        if sub.exists() and not sub.is_dir():
            raise CamplaceError(f"{option}: {sub} is a file, but this verb writes a folder there "
                                f"(move that file away, or give another -o folder)")
    return path


def check_out_file(path: str | Path, option: str = "-o/--out", *, example: str = "out.json", fix: str | None = None) -> Path:
    """Check that ``path`` can be written as a file (it is not a folder, nor inside a file).

    Parameters
    ----------
    path : path
    option : str
        The option that gave it, for the message.
    example : str
        A file name to suggest inside the folder when ``path`` is a folder (e.g. ``"solve.json"``).
    fix : str or None
        The fix to name instead when ``path`` is a folder (for a verb whose file name is fixed).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    CamplaceError
    """
    path = Path(path)
    if path.is_dir():
        raise CamplaceError(f"{option}: {path} is a folder, not a file ({fix or f'give a file name such as {path / example}'})")
    _check_parents(path, option)
    return path


def check_new_file(path: str | Path, option: str = "-o/--out", *, force: bool = False) -> Path:
    """:func:`check_out_file`, and refuse to replace an existing file unless ``force``.

    Raises
    ------
    CamplaceError
        When ``path`` exists and ``force`` is False (the message names ``--force``).
    """
    path = check_out_file(path, option, example=Path(path).name or "file")
    if path.exists() and not force:
        raise CamplaceError(f"{option}: {path} already exists (add --force to replace it, or give another file name)")
    return path
