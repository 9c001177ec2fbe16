"""Memory estimate of a dense BEM system, and a refusal before assembling what does not fit.

A dense collocation system of ``N`` unknowns stores one ``N x N`` float64
matrix (8 N^2 bytes), factorised in place; the right-hand sides and the
assembly's scratch add a few ``N``-vectors per electrode.

Example
-------
>>> from electrosense.bem.memory import dense_system_bytes
>>> dense_system_bytes(10_000) / 1e9
0.8
"""
from __future__ import annotations

__all__ = ["dense_system_bytes", "check_memory", "check_bytes", "MemoryRefusal"]


class MemoryRefusal(MemoryError, ValueError):
    """The dense system would not fit in this machine's memory."""


def dense_system_bytes(n_unknowns: int, n_matrices: float = 1.0) -> float:
    """Bytes of ``n_matrices`` dense ``n x n`` float64 matrices."""
    return 8.0 * n_matrices * float(n_unknowns) ** 2


def available_bytes() -> float:
    """Memory available to this process now (bytes), from psutil."""
    import psutil

    return float(psutil.virtual_memory().available)


def check_memory(n_unknowns: int, n_matrices: float = 1.0, what: str = "the BEM system",
                 fraction: float = 0.8, hint: str = "raise edge_length_m (coarser sensor mesh) or coarsen the tank mesh") -> float:
    """Return the estimated bytes, or raise :class:`MemoryRefusal` past ``fraction`` of available memory."""
    return check_bytes(dense_system_bytes(n_unknowns, n_matrices), f"{what} has {n_unknowns} unknowns and", fraction,
                       hint)


def check_bytes(need: float, what: str = "the BEM system", fraction: float = 0.8,
                hint: str = "raise edge_length_m (coarser sensor mesh) or coarsen the tank mesh") -> float:
    """Return ``need`` (bytes), or raise :class:`MemoryRefusal` if it exceeds ``fraction`` of available memory
    (a share of it where several processes hold such blocks at once: ``fraction`` divided among them)."""
    have = available_bytes()
    if need > fraction * have:
        share = "" if fraction >= 0.8 else f" (its share, {fraction:.2g} of them, with other processes beside it)"
        raise MemoryRefusal(
            f"{what} needs about {need / 1e9:.1f} GB as dense matrices, but only {have / 1e9:.1f} GB of memory are "
            f"available{share}: {hint}"
        )
    return need
