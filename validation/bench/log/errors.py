"""The one error a bench-log reader or writer raises on bad input.

Example
-------
>>> from electrosense.validation.bench.log.errors import BenchLogError
>>> str(BenchLogError("run.csv", 7, "time goes backwards (t_s 1.2 after 1.3)"))
'run.csv, line 7: time goes backwards (t_s 1.2 after 1.3)'
"""
from __future__ import annotations

__all__ = ["BenchLogError"]


class BenchLogError(ValueError):
    """Bad bench-log input, with where it is and why it is refused.

    Parameters
    ----------
    file : str
        The file (as given by the caller).
    line : int or None
        1-based line number, ``None`` when the problem is not on one line.
    reason : str
        What is wrong, in words.
    """

    def __init__(self, file, line: int | None, reason: str):
        self.file = str(file)
        self.line = line
        self.reason = reason
        where = self.file if line is None else f"{self.file}, line {line}"
        super().__init__(f"{where}: {reason}")

    def __reduce__(self):  # picklable across processes (dask, multiprocessing)
        return (type(self), (self.file, self.line, self.reason))
