"""Progress of a long run, on a terminal and off it.

On a terminal, a tqdm bar on standard error. Off a terminal (a pipe, a CI log, a file), one line
per finished unit of work on standard error, with the count, the elapsed time and an estimate of
what remains::

    rangeslam: fig3: 12/40 trials (sigma=0.001 done), 31 s elapsed, about 1 min 12 s left

Lines are at least ``min_interval`` seconds apart except for the ones that close a named stage
(a benchmark cell, a method), so a log of a long run stays readable. Results go to standard
output; progress never does.
"""

from __future__ import annotations

import io
import logging
import os
import sys
import threading
import time
from typing import TextIO

__all__ = ["HEARTBEAT_SECONDS", "Heartbeat", "Progress", "bar_size", "format_seconds"]

#: Seconds between two lines of a :class:`Heartbeat` (a run, a demo's rooms, a long simulation).
HEARTBEAT_SECONDS = 10.0


def format_seconds(seconds: float) -> str:
    """``seconds`` as '8.2 s', '3 min 05 s' or '1 h 02 min'."""
    if not seconds < float("inf"):
        return "unknown"
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


def bar_size(stream) -> dict:
    """tqdm's ``ncols`` and ``nrows`` for a bar on the terminal ``stream``: none (tqdm measures
    the terminal), or 80 x 24 when the terminal says it has no size (a pseudo-terminal nobody
    sized: ``docker exec -t``, ``script``, some IDE consoles), where tqdm draws nothing at all
    (it takes the bar's row as beyond the last one)."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        return {}
    return {"ncols": 80, "nrows": 24} if min(size.columns, size.lines) <= 0 else {}


class Progress:
    """Counts finished units of a run of ``total`` and shows it (a context manager).

    Args:
        total: number of units (trials, methods, RIRs), >= 0.
        label: what runs, as the line's prefix ('fig3', 'Plaza1 methods').
        unit: the units' name, plural ('trials').
        stream: where to write; default standard error.
        tty: draw a tqdm bar (True) or print lines (False); default: whether ``stream`` is a
            terminal.
        min_interval: least seconds between two lines off a terminal, except lines that close
            a stage; 0 prints every unit.
        enabled: False shows nothing (a quiet run, tests).
    """

    def __init__(
        self,
        total: int,
        label: str,
        *,
        unit: str = "trials",
        stream: TextIO | None = None,
        tty: bool | None = None,
        min_interval: float = 2.0,
        enabled: bool = True,
    ) -> None:
        self.total = int(total)
        self.label = label
        self.unit = unit
        self.stream = sys.stderr if stream is None else stream
        if tty is None:
            isatty = getattr(self.stream, "isatty", None)
            tty = bool(isatty and isatty())
        self.min_interval = float(min_interval)
        self.enabled = enabled
        self.done = 0
        self.started = time.perf_counter()
        self.last_line = -float("inf")
        self.bar = None
        if enabled and tty:
            from tqdm import tqdm

            self.bar = tqdm(
                total=self.total,
                desc=label,
                unit=unit[:-1] or unit,
                file=self.stream,
                **bar_size(self.stream),
            )

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    @property
    def elapsed(self) -> float:
        """Seconds since the run started."""
        return time.perf_counter() - self.started

    def remaining(self) -> float:
        """Estimated seconds left: the mean time per finished unit times the units left."""
        if self.done == 0:
            return float("inf")
        return self.elapsed / self.done * max(self.total - self.done, 0)

    def update(self, n: int = 1, *, stage: str | None = None) -> None:
        """``n`` more units finished; ``stage`` names what they closed (a cell, a method)."""
        self.done += n
        if not self.enabled:
            return
        if self.bar is not None:
            if stage:
                self.bar.set_postfix_str(stage, refresh=False)
            self.bar.update(n)
            return
        now = time.perf_counter()
        last = self.done >= self.total
        if stage is None and not last and now - self.last_line < self.min_interval:
            return
        self.last_line = now
        print(self.line(stage), file=self.stream, flush=True)

    def line(self, stage: str | None = None) -> str:
        """The line shown off a terminal."""
        what = f" ({stage} done)" if stage else ""
        left = "" if self.done >= self.total else f", about {format_seconds(self.remaining())} left"
        return (
            f"rangeslam: {self.label}: {self.done}/{self.total} {self.unit}{what}, "
            f"{format_seconds(self.elapsed)} elapsed{left}"
        )

    def close(self) -> None:
        """Close the bar (the lines need no closing)."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None


class Heartbeat(logging.Handler):
    """Progress of one long call whose length is not known in advance (a context manager).

    Every ``interval`` seconds (default :data:`HEARTBEAT_SECONDS`) it writes a line on standard error with the time elapsed and the
    step under way: the latest INFO message of the ``rangeslam`` loggers (the library logs its
    steps with :func:`rangeslam.logsteps.logged_step`)::

        rangeslam: run: 20 s elapsed; walk: SLAM on the tracks at the steps (EDM start, ...) ...

    ``step`` is what runs until the library logs a step. Without ``-v`` the records it reads are
    not printed; with it they are, as before.
    """

    def __init__(
        self,
        label: str,
        *,
        interval: float | None = None,
        stream: TextIO | None = None,
        enabled: bool = True,
        step: str = "",
    ) -> None:
        super().__init__(level=logging.INFO)
        self.label = label
        self.interval = float(HEARTBEAT_SECONDS if interval is None else interval)
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.step = step
        self._given = step
        self._open: list[str] = []  # the steps under way, as their start messages
        self.lines = 0
        self.started = time.perf_counter()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._logger = logging.getLogger("rangeslam")
        self._saved: tuple[int, bool] | None = None

    def emit(self, record: logging.LogRecord) -> None:
        """Keep the step under way: a step's start ("what ...") is the step; its end ("what:
        done in ..." or "what: failed after ...") goes back to the step it ran in (the step
        given at the start when none), so a line never reports a finished step as under way."""
        message = record.getMessage()
        if message.endswith(" ..."):
            self._open.append(message)
        else:
            ended = message.split(": done in ")[0].split(": failed after ")[0] + " ..."
            if ended not in self._open:  # another message of the library: what it does now
                self.step = message
                return
            self._open.remove(ended)
        self.step = self._open[-1] if self._open else self._given

    def line(self) -> str:
        """The line written now."""
        step = f"; {self.step}" if self.step else ""
        elapsed = format_seconds(time.perf_counter() - self.started)
        return f"rangeslam: {self.label}: {elapsed} elapsed{step}"

    def _beat(self) -> None:
        while not self._stop.wait(self.interval):
            print(self.line(), file=self.stream, flush=True)
            self.lines += 1

    def __enter__(self) -> Heartbeat:
        if not self.enabled:
            return self
        self.started = time.perf_counter()
        log = self._logger
        if not log.isEnabledFor(logging.INFO):  # not verbose: read the steps, do not print them
            self._saved = (log.level, log.propagate)
            log.setLevel(logging.INFO)
            log.propagate = False
        log.addHandler(self)
        self._thread = threading.Thread(target=self._beat, name="rangeslam-heartbeat", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc_info) -> None:
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join()
        self._thread = None
        self._logger.removeHandler(self)
        if self._saved is not None:
            self._logger.setLevel(self._saved[0])
            self._logger.propagate = self._saved[1]
            self._saved = None
