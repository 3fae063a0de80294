"""Errors that camplace reports to users as one clean line (CLI exit code 2)."""

from __future__ import annotations


class CamplaceError(Exception):
    """A user-facing error: bad input, an impossible request, a missing file.

    The CLI prints ``error: <message>`` on one line and exits with code 2, without a traceback.
    Messages name the file and/or field at fault and say how to fix it.
    """


class InstanceError(CamplaceError):
    """An instance file (or built-in) is malformed.

    Parameters
    ----------
    source : str
        The file (or built-in name) the problem is in.
    field : str
        Dotted path of the offending field, e.g. ``camera.focal_length_mm`` or ``frames[2].weight``.
    problem : str
        What is wrong, e.g. ``must be > 0, got -3.0``.
    fix : str, optional
        How to fix it, e.g. ``set a positive focal length in millimetres``.
    """

    def __init__(self, source: str, field: str, problem: str, fix: str | None = None) -> None:
        self.source = source
        self.field = field
        self.problem = problem
        self.fix = fix
        msg = f"{source}: {field}: {problem}" if field else f"{source}: {problem}"
        if fix:
            msg += f" ({fix})"
        super().__init__(msg)


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``n`` and the noun in the right number, for messages: ``plural(1, "frame")`` is ``"1 frame"``,
    ``plural(3, "frame")`` is ``"3 frames"`` (``nouns``: an irregular plural)."""
    return f"{n} {noun if n == 1 else (nouns or noun + 's')}"
