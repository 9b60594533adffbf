"""The progress display of `cmrt optimize`, `cmrt submit --wait` and `cmrt watch`: a rich
progress bar (generation, evaluations of the cap, best, sigma, elapsed) on a terminal, and one
plain line per generation otherwise (logs, pipes, tests), in the format `cmrt optimize` has
always printed: `gen    3  evals    24  best    2.8268  sigma  0.1454     17.1 s`.
"""

from __future__ import annotations

import math
import sys
from types import TracebackType
from typing import IO

from cmrt.client import Progress


def is_terminal(stream: IO[str]) -> bool:
    """True when the bar can be drawn: `stream` and stdout are both terminals (piping or
    redirecting either one gives plain lines)."""
    try:
        return stream.isatty() and sys.stdout.isatty()
    except (AttributeError, ValueError):  # closed or replaced streams
        return False


def _num(v: float | None, fmt: str) -> str:
    return "-" if v is None or not math.isfinite(v) else format(v, fmt)


class ProgressDisplay:
    """`with ProgressDisplay(sys.stderr, title) as show: show(progress)`; `bar=None` decides
    by `is_terminal(stream)`."""

    def __init__(self, stream: IO[str], title: str, bar: bool | None = None) -> None:
        self.stream = stream
        self.title = title
        self.bar = is_terminal(stream) if bar is None else bar
        self._rich = None
        self._task = None
        self._printed: int | None = None  # last generation printed as a plain line

    def __enter__(self) -> ProgressDisplay:
        if self.bar:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn
            from rich.progress import Progress as RichProgress

            # Fits 80 columns: name, generation, bar, evaluations of the cap, best, sigma,
            # elapsed (the job's, by the server's clock, not the time since this started).
            self._rich = RichProgress(
                TextColumn("[bold]{task.description}"),
                TextColumn("gen {task.fields[generation]:>3}"),
                BarColumn(bar_width=12),
                MofNCompleteColumn(),
                TextColumn("evals  best {task.fields[best]}  sigma {task.fields[sigma]}"),
                TextColumn("{task.fields[elapsed]:>6} s"),
                console=Console(file=self.stream), refresh_per_second=4)
            self._rich.__enter__()
            self._task = self._rich.add_task(self.title, total=None, generation="-",
                                             best="-", sigma="-", elapsed="0.0")
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._rich is not None:
            self._rich.__exit__(exc_type, exc, tb)

    def __call__(self, p: Progress) -> None:
        if self._rich is not None:
            title = self.title if p.status == "running" else f"{self.title} {p.status}"
            self._rich.update(
                self._task, description=title, completed=p.evaluations,
                total=p.max_evaluations,
                generation="-" if p.generation is None else str(p.generation),
                best=_num(p.best, ".4f"), sigma=_num(p.sigma, ".4f"),
                elapsed=f"{p.elapsed:.1f}")
            return
        lines = p.generation_lines() if p.new else []
        if not lines and p.generation is not None and p.generation != self._printed:
            lines = [p.line()]  # a caller that does not list generations (cmrt optimize)
        for line in lines:
            print(line, file=self.stream, flush=True)
        if p.generation is not None:
            self._printed = p.generation
