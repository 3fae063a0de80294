"""Progress display per pipeline stage: rich bars on a terminal, one line per stage otherwise."""

from __future__ import annotations

import contextlib
import sys
import time
from typing import Callable, Iterator

from camplace._signals import check_ctrl_c


class Reporter:
    """Silent progress reporter (the default for the Python API)."""

    @contextlib.contextmanager
    def stage(self, name: str, total: int | None = None) -> Iterator[Callable[[int], None]]:
        """Context for one stage; yields ``advance(n)``. A noted Ctrl-C
        (:func:`camplace._signals.check_ctrl_c`) is raised at the start and at every step."""
        check_ctrl_c()
        yield lambda n=1: check_ctrl_c()


class ConsoleReporter(Reporter):
    """Rich progress bars on stderr when it is a terminal; otherwise a line per finished stage."""

    def __init__(self, stream=None) -> None:
        self.stream = stream or sys.stderr
        self.live = bool(getattr(self.stream, "isatty", lambda: False)())

    @contextlib.contextmanager
    def stage(self, name: str, total: int | None = None) -> Iterator[Callable[[int], None]]:
        check_ctrl_c()
        t0 = time.perf_counter()
        if self.live:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            with Progress(
                TextColumn("{task.description:<12}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=Console(file=self.stream),
                transient=False,
            ) as prog:
                task = prog.add_task(name, total=total)
                def advance(n: int = 1) -> None:
                    check_ctrl_c()
                    prog.advance(task, n)

                yield advance
                if total is None:
                    prog.update(task, total=1, completed=1)
        else:
            yield lambda n=1: check_ctrl_c()
            print(f"{name:<12} done in {time.perf_counter() - t0:.2f} s", file=self.stream, flush=True)
