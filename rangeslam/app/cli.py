"""The ``rangeslam`` command. It parses, calls library functions and writes; no math lives here.

The parser is :mod:`rangeslam.app.parser`; the commands are :mod:`rangeslam.app.demo_command`,
:mod:`rangeslam.app.bench_command` and :mod:`rangeslam.app.run_command`; the report writers
:mod:`rangeslam.app.reports`.
"""

from __future__ import annotations

import logging
import sys

from rangeslam.app.parser import build_parser

__all__ = ["build_parser", "main"]


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` (default: the command line), run the command, return its exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s"
    )
    from rangeslam.errors import RangeSlamError

    try:
        return int(args.func(args))
    except RangeSlamError as exc:
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # an output that cannot be written: one line, no traceback
        print(f"rangeslam: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    raise SystemExit(main())
