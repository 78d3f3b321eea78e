"""athermal's benchmarks: scripts run as modules from the repository root,
``python -m benchmarks.NAME [--help]`` (``benchmarks/README.md``).

They use athermal's public API; the internal names they need are listed, with the reason, in
``benchmarks/README.md`` ("What the scripts import") and checked by
``tests/test_benchmarks_layout.py``. ``benchmarks.machine`` is the shared preamble (the run's
machine, pinning, writing results). Nothing is imported here: ``kernels`` sets its thread
variables before numpy is first imported.
"""
