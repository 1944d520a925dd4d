"""Run time against error, per processor: `python -m usdbake.benchmarks [NAME ...] [--quick]`.

Each ``bench_<name>.py`` module defines ``NAME``, ``DESCRIPTION`` and
``run(quick: bool) -> dict`` returning a result made with
``harness.result(...)``; the runner saves it to ``results/<name>.json`` and
regenerates ``docs/benchmarks.md`` (tables and log-log time/error plots with
the Pareto front and the default setting marked) from every saved result.
"""
