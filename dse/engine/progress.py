"""Progress bars on stderr (tqdm), silent when stderr is not a terminal unless forced. tqdm is imported only
when a bar is shown: a command without bars (`dse check`, a run in a script or CI) does not load it."""
from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING, Iterable, TypeVar

if TYPE_CHECKING:
    from tqdm import tqdm

T = TypeVar("T")


def progress_enabled() -> bool:
    flag = os.environ.get("DSE_PROGRESS")
    if flag is not None:
        return flag not in ("0", "", "false", "no")
    return sys.stderr.isatty()


def progress(iterable: Iterable[T], *, desc: str = "", total: int | None = None) -> Iterable[T]:
    """`iterable` with a bar when bars are shown, else `iterable` itself."""
    if not progress_enabled():
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, leave=False, dynamic_ncols=True, file=sys.stderr)


def counter(total: int, *, desc: str = "", unit: str = "it") -> tqdm | _Count:
    """A progress bar advanced by hand (`bar.update(k)`, `bar.n` the count so far), with the time left; use as a
    context manager. Without bars, a counter alone (tqdm takes 30 ms to import)."""
    if not progress_enabled():
        return _Count(total)
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, unit_scale=True, leave=False, dynamic_ncols=True, file=sys.stderr)


class _Count:
    """What `counter` gives when no bar is shown: the count, advanced by `update`."""

    def __init__(self, total: int):
        self.total, self.n = total, 0

    def update(self, k: int = 1) -> None:
        self.n += k

    def close(self) -> None:
        pass

    def __enter__(self) -> "_Count":
        return self

    def __exit__(self, *exc) -> None:
        pass


def fresh_line() -> str:
    """What to write before a last message so that it starts its own line when a bar may be left on screen (an
    interrupted loop does not close its bar): clear the line on a terminal, end it otherwise."""
    if not progress_enabled():
        return ""
    return "\r\x1b[K" if sys.stderr.isatty() else "\n"


class note_if_slow:
    """Print `message` on stderr once if the block it wraps is still running after `delay` seconds (a
    command that would otherwise be silent says what it is doing); use as a context manager."""

    def __init__(self, delay: float, message: str):
        import threading

        self._timer = threading.Timer(delay, self._note, args=(message,))
        self._timer.daemon = True
        self.noted = threading.Event()      # set once the message is printed

    def _note(self, message: str) -> None:
        print(message, file=sys.stderr, flush=True)
        self.noted.set()

    def __enter__(self) -> "note_if_slow":
        self._timer.start()
        return self

    def __exit__(self, *exc) -> None:
        self._timer.cancel()
