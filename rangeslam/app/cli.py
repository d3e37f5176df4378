"""The ``rangeslam`` command. It parses, calls library functions and writes; no math lives here.

The parser is :mod:`rangeslam.app.parser`; the commands are :mod:`rangeslam.app.demo_command`,
:mod:`rangeslam.app.bench_command`, :mod:`rangeslam.app.simulate_command` and
:mod:`rangeslam.app.run_command`; the report writers :mod:`rangeslam.app.reports`. Exit codes:
0 converged, 1 not converged or a solver failure (the reason printed), 2 bad input, 130
interrupted.
"""

from __future__ import annotations

import logging
import sys

from rangeslam.app.parser import build_parser

__all__ = ["StderrLog", "build_parser", "main"]


class StderrLog(logging.Handler):
    """rangeslam's log as lines ``rangeslam: message`` on the standard error of the moment."""

    def emit(self, record: logging.LogRecord) -> None:
        """Print the record's message."""
        print(f"rangeslam: {record.getMessage()}", file=sys.stderr, flush=True)


def _log_to_stderr(*, verbose: bool) -> None:
    """rangeslam's log on standard error: its steps and times with -v (INFO), else warnings."""
    log = logging.getLogger("rangeslam")
    handler = next((h for h in log.handlers if isinstance(h, StderrLog)), None)
    if handler is None:
        handler = StderrLog()
        log.addHandler(handler)
    level = logging.INFO if verbose else logging.WARNING
    handler.setLevel(level)
    log.setLevel(level)


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` (default: the command line), run the command, return its exit code."""
    args = build_parser().parse_args(argv)
    _log_to_stderr(verbose=getattr(args, "verbose", False))
    from rangeslam.errors import InvalidInputError, RangeSlamError

    try:
        return int(args.func(args))
    except InvalidInputError as exc:  # bad input found past the parser: exit 2, as documented
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 2
    except RangeSlamError as exc:
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # an output that cannot be written: one line, no traceback
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("rangeslam: interrupted; what finished is in the output folder", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
