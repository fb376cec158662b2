"""Solving the compact coupled biharmonic scheme for all handles at once: the operator, the multigrid
preconditioner, batched conjugate gradients, and the memory plan (handle chunks)."""

from .budget import MemoryEstimate, available_memory, estimate_memory, plan_chunks
from .multigrid import Multigrid, coarsen
from .preconditioner import Jacobi, Preconditioner
from .solve import SolveReport, apply_operator, solve_biharmonic

__all__ = ["MemoryEstimate", "available_memory", "estimate_memory", "plan_chunks", "Multigrid", "coarsen", "Jacobi",
           "Preconditioner", "SolveReport", "apply_operator", "solve_biharmonic"]
