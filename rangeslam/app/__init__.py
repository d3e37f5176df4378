"""The application: the ``rangeslam`` command, experiments, benchmarks, reports and plots.

Nothing here is imported by the library; the command imports what it runs lazily.
"""
