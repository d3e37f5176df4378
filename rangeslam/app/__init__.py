"""The application: the ``rangeslam`` command, experiments, benchmarks, reports and plots.

- :mod:`.cli`: ``main``, the console script; :mod:`.parser`: its argument parser.
- :mod:`.demo_command`, :mod:`.bench_command`, :mod:`.run_command` (with :mod:`.run_report`):
  one function per command.
- :mod:`.reports`: Markdown, CSV, JSON and TUM writers.
- :mod:`.experiments`, :mod:`.benchmarking`, :mod:`.plaza_bench`: simulated experiments and
  benchmarks as library functions; :mod:`.plotting`: the figures.

Nothing here is imported by the library; the command imports what it runs lazily. Errors against
the truth come from :mod:`rangeslam.evaluation`.
"""
