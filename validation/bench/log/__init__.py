"""Bench logs (format version 1): strict reader, crash-safe writer.

The format is the project's bench-log spec: ``# esense-bench-log 1``, a
``# meta: {json}`` line, optional ``#`` comments, a column row, then one CSV
row per sample (t_s, x_m, y_m, z_m, yaw_rad, U_V, I<k>_A per receiver, and
optional columns).

Example
-------
>>> from electrosense.validation.bench.log import read_bench_log
>>> log = read_bench_log("run.csv")          # doctest: +SKIP
>>> log.poses.shape, log.currents_A.shape    # doctest: +SKIP
((161, 4), (161, 3))
"""
from electrosense.validation.bench.log.errors import BenchLogError
from electrosense.validation.bench.log.header import receiver_columns, standard_columns
from electrosense.validation.bench.log.reader import BenchLog, read_bench_log, read_bench_logs, read_header
from electrosense.validation.bench.log.writer import BenchLogWriter, format_value, write_bench_log

__all__ = [
    "BenchLog", "BenchLogError", "BenchLogWriter", "read_bench_log", "read_bench_logs", "read_header",
    "write_bench_log", "format_value", "receiver_columns", "standard_columns",
]
