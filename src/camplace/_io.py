"""Atomic file output: write to a temporary file in the same directory, then rename.

A crash, Ctrl-C or a full disk never leaves a half-written output file behind.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterator

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` when the block succeeds.

    The temporary file keeps ``path``'s suffix (some writers, e.g. ``scipy.sparse.save_npz`` and
    trimesh, decide the format from it). On any exception the temporary file is removed and
    ``path`` is left untouched.
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    sfx = final.suffix if suffix is None else suffix
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=f".tmp{sfx}", dir=final.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    # mkstemp creates 0600 files; give outputs the usual permissions (0666 less the umask)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield tmp
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


@contextlib.contextmanager
def staged_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``path``; move its entries into ``path`` when the block succeeds.

    For verbs that write many files into a folder (``render``, ``validate``): an interrupted or
    failed block leaves ``path`` as it was (no photograph or figure of a half-done run). On success
    each entry of the temporary folder replaces the entry of the same name in ``path`` (a
    sub-folder as a whole, so no stale file of an earlier run stays in it); other entries of
    ``path`` are kept. Folders created above ``path`` for the temporary folder are removed again
    on failure.

    Parameters
    ----------
    path : path
        The output folder (created when missing).

    Yields
    ------
    Path
        The temporary folder (``.<name>.<random>.tmp`` beside ``path``).
    """
    final = Path(path)
    created = [p for p in (final.parent, *final.parent.parents) if not p.exists()]
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent))
    done = False
    try:
        yield tmp
        _move_entries(tmp, final)
        done = True
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        for p in [] if done else created:  # innermost first
            with contextlib.suppress(OSError):
                p.rmdir()


def _move_entries(src: Path, dst: Path) -> None:
    """Move every entry of folder ``src`` into folder ``dst``, replacing entries of the same name."""
    dst.mkdir(exist_ok=True)
    for entry in src.iterdir():
        target = dst / entry.name
        if target.is_dir() and not target.is_symlink():
            shutil.rmtree(target)
        elif entry.is_dir() and (target.exists() or target.is_symlink()):
            target.unlink()
        os.replace(entry, target)


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | os.PathLike[str], obj: Any) -> None:
    """Write ``obj`` as indented JSON (sorted keys, trailing newline) atomically."""
    write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n")


def write_with_atomic(path: str | os.PathLike[str], writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)`` and rename the result onto ``path`` atomically."""
    with atomic_path(path) as tmp:
        writer(tmp)


def csv_text(header: str, columns: "list[np.ndarray]") -> str:
    """A CSV file's text: ``header``, then one line per row of the given columns, floats written as
    Python's ``repr`` (the shortest text that reads back to the same float64), integers as ``str``.

    Parameters
    ----------
    header : str
        The first line, without its newline.
    columns : list of (n,) arrays
        Float (kind ``f``) or integer columns, all of one length.

    Returns
    -------
    str
        Every line ends with a newline. Formatted column by column with ``map`` and joined with
        ``zip`` (no Python loop per value); a column of few distinct values (a frame's weight,
        a face's normal, a fixed aim) formats each distinct value once (:func:`_column_text`).
    """
    import numpy as np

    texts = [_column_text(np.asarray(c)) for c in columns]
    sizes = {len(t) for t in texts}
    if len(sizes) > 1:
        raise ValueError(f"csv_text: columns of different lengths {sorted(sizes)}")
    body = "\n".join(map(",".join, zip(*texts)))
    return header + "\n" + (body + "\n" if body else "")


#: a column of at least this many values is checked for repeats (below, formatting it is cheap)
_REPEAT_MIN = 4096


def _column_text(a: "np.ndarray") -> list[str]:
    """Each value of ``a`` (n,) as text: floats as ``repr``, integers as ``str``.

    A long column of at most 80 % distinct values (counted on a sorted copy, about 1 % of the cost
    of formatting) is formatted through its distinct values, compared bit for bit (so ``-0.0``
    keeps its sign): the same text as formatting every value, each distinct value formatted once."""
    import numpy as np

    fmt = repr if a.dtype.kind == "f" else str
    if a.size >= _REPEAT_MIN:
        key = a.view(np.dtype(f"u{a.dtype.itemsize}")) if a.dtype.kind == "f" else a
        ranked = np.sort(key)
        new = np.concatenate(([True], ranked[1:] != ranked[:-1]))
        if 5 * np.count_nonzero(new) <= 4 * a.size:
            distinct = ranked[new]
            texts = list(map(fmt, distinct.view(a.dtype).tolist()))
            return list(map(texts.__getitem__, np.searchsorted(distinct, key).tolist()))
    return list(map(fmt, a.tolist()))


def read_json(path: str | os.PathLike[str], default_name: str, what: str) -> Any:
    """Read a JSON file, or ``default_name`` inside ``path`` when ``path`` is a folder.

    Raises
    ------
    CamplaceError
        One line naming the file when it cannot be read or parsed.
    """
    from camplace.errors import CamplaceError

    p = Path(path)
    if p.is_dir():
        p = p / default_name
    try:
        return json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CamplaceError(f"{p}: cannot read the {what} ({exc})") from None


def read_numeric_csv(path: str | os.PathLike[str], header: str, what: str) -> "np.ndarray":
    """Read a camplace CSV of numbers whose first line must be ``header``.

    Parameters
    ----------
    path : path
    header : str
        The exact header (spaces ignored); its comma count gives the number of columns.
    what : str
        What the file is, for error messages (e.g. "candidates file").

    Returns
    -------
    (rows, columns) float64
        Finite values; a row index first column is checked to run 0, 1, 2, ...

    Raises
    ------
    CamplaceError
        One line naming the file and the problem.
    """
    import numpy as np

    from camplace.errors import CamplaceError

    path = Path(path)
    n_cols = header.count(",") + 1
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise CamplaceError(f"{path}: cannot read the {what} ({reason}; check the path)") from None
    if not lines or lines[0].replace(" ", "") != header:
        raise CamplaceError(f"{path}: the header must be '{header}' (write it with camplace)")
    try:
        data = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]], dtype=np.float64)
    except ValueError as exc:
        raise CamplaceError(f"{path}: every row needs {n_cols} numbers ({exc})") from None
    data = data.reshape(-1, n_cols) if data.size else np.empty((0, n_cols))
    if data.shape[1] != n_cols:
        raise CamplaceError(f"{path}: every row needs {n_cols} numbers")
    if not np.all(np.isfinite(data)):
        raise CamplaceError(f"{path}: contains NaN or infinite values")
    if header.startswith("index,") and not np.array_equal(data[:, 0], np.arange(len(data))):
        raise CamplaceError(f"{path}: the index column must run 0, 1, 2, ... (was the file edited?)")
    return data


_TEMP = re.compile(r"^\..+\.[A-Za-z0-9_]{8}\.tmp(\.[A-Za-z0-9]+)?$")


def remove_stale_temps(directory: str | os.PathLike[str]) -> int:
    """Delete temporary files that :func:`atomic_path` left behind when a process was killed.

    Only names of its own pattern (``.<name>.<8 random chars>.tmp[.suffix]``) are touched.
    Returns how many were removed.
    """
    d = Path(directory)
    if not d.is_dir():
        return 0
    n = 0
    for p in d.iterdir():
        if p.is_file() and _TEMP.match(p.name):
            with contextlib.suppress(OSError):
                p.unlink()
                n += 1
    return n
