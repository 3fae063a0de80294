"""Errors that camplace reports to users as one clean line, and the exit codes of every verb.

The exit codes have this one home; every verb of the command line returns them with the same
meaning:

====  ==========================================================================================
0     success
1     the command finished, but no feasible camera system (or plan) exists for what was asked
2     bad input: one ``error: ...`` line naming the file or option and the fix; nothing written
3     an input could not be read or an output written (disk full, permissions): one line, no
      partial file
130   interrupted (Ctrl-C): no partial output
====  ==========================================================================================
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_NO_SOLUTION = 1
EXIT_BAD_INPUT = 2
EXIT_IO = 3
EXIT_INTERRUPTED = 130


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
