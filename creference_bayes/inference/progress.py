"""Progress bars (tqdm) on standard error, in one place: how they look and where they go.

Callers decide *whether* to show one; a run of units whose standard error is not a terminal prints
a line per unit instead (:class:`LineBar`). The bars are tqdm's plain text bars (``tqdm.std``),
also inside Jupyter (``tqdm.auto`` warns on import in a kernel without ipywidgets).
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager

__all__ = ["progress_bar", "progress_mode", "SilentBar", "LineBar"]


def progress_mode(quiet: bool, stream=None):
    """How the command line reports a long run of units: False (``--quiet``), True (a bar:
    ``stream``, standard error by default, is a terminal) or ``"lines"`` (a line per unit)."""
    if quiet:
        return False
    stream = sys.stderr if stream is None else stream
    return True if stream.isatty() else "lines"


class SilentBar:
    """What a disabled bar does (count, and nothing else), without tqdm.

    A tqdm bar, even a disabled one, creates a ``multiprocessing`` lock, a named semaphore
    registered with the resource tracker; a batch worker process ended by the batch (an
    interrupt, a time limit) never releases it, and Python then warns about leaked semaphores.
    """

    def __init__(self, total: int | None = None, initial: int = 0):
        self.total, self.n = total, initial

    def update(self, n: int = 1) -> None:
        self.n += n

    def set_postfix_str(self, *args, **kwargs) -> None:
        pass

    def close(self) -> None:
        pass

    @contextmanager
    def external_write_mode(self, file=None, nolock: bool = False):
        yield

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> bool:
        return False


class LineBar(SilentBar):
    """A line on standard error per update, for a log file: ``batch 3/48: <postfix> (12 s)``, the
    postfix as :meth:`set_postfix_str` last set it (what the unit was and how it ended)."""

    def __init__(self, total: int | None = None, initial: int = 0, desc: str | None = None, unit: str = "it"):
        super().__init__(total, initial)
        self.desc, self.unit, self.note, self.start = desc or "progress", unit, "", time.monotonic()

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.note = s

    def update(self, n: int = 1) -> None:
        super().update(n)
        count = f"{self.n}/{self.total}" if self.total is not None else f"{self.n}"
        what = f": {self.note}" if self.note else f" {self.unit}{'s' if self.n != 1 else ''}"
        print(f"{self.desc} {count}{what} ({time.monotonic() - self.start:.0f} s)", file=sys.stderr, flush=True)
        self.note = ""


def progress_bar(enabled: bool | str, total: int | None = None, *, desc: str | None = None,
                 unit: str = "it", initial: int = 0, leave: bool = False, postfix: dict | None = None):
    """A ``tqdm.std.tqdm`` on standard error that disappears when done (``leave``: it stays), a
    :class:`LineBar` when ``enabled`` is ``"lines"``, or a :class:`SilentBar`; the other arguments
    are tqdm's. Usable as a context manager; ``update(n)`` advances it."""
    if enabled == "lines":
        return LineBar(total, initial, desc, unit)
    if not enabled:
        return SilentBar(total, initial)
    from tqdm.std import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, initial=initial,
                leave=leave, dynamic_ncols=True, postfix=postfix)
