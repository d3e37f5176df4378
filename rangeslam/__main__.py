"""``python -m rangeslam``: the ``rangeslam`` command."""

from rangeslam.app.cli import main

raise SystemExit(main())
