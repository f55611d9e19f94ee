"""What a model's Cholesky factor will cost, from its mesh alone: the fill of K and of L, and the work.

A model too big for the machine should say so before anything is assembled (issue 41). K of a mesh with three
DOFs per node is the node graph (two nodes coupled when they share a cell) with a 3 x 3 block per coupling, so
PARDISO's symbolic analysis (METIS ordering and symbolic factorisation, phase 11) of the node graph, nine times
smaller than K, gives the factor of K by the block rule: ``nnz(L_K) = 9 (nnz(L_nodes) - n) + 6 n`` (an
off-diagonal block has 9 entries, a diagonal block's lower triangle 6) and ``flop(K) = 27 flop(nodes)`` (every
scalar operation of the node factor is a 3 x 3 block operation). METIS orders the node graph as it would K's
blocks, so the estimate is close: on the bracket's tet10 meshes of 118k-464k DOFs within a few per cent of the
fill PARDISO reports for K itself (``docs/results/scaling.md``). Nodes supported in every direction leave the graph as their
rows leave K; other supports are kept (an upper bound).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["Fill", "node_graph", "mesh_fill"]


@dataclass(frozen=True)
class Fill:
    """The size of a mesh model's matrices and factor.

    Attributes
    ----------
    n_dofs : int
        ``dofs_per_node x n_nodes`` of the nodes not supported in every direction.
    nnz_K : int
        Stored entries of K (both triangles).
    nnz_L : int
        Entries of the Cholesky factor L of K.
    factor_mflop : float
        Work of the numerical factorisation, 1e6 floating point operations.
    """

    n_dofs: int
    nnz_K: int
    nnz_L: int
    factor_mflop: float


def node_graph(cells: np.ndarray, n_nodes: int) -> sp.csr_matrix:
    """The node coupling graph, shape (n_nodes, n_nodes): ``(i, j)`` stored when nodes i and j share a cell
    (the diagonal included), values 1."""
    cells = np.asarray(cells)
    n_cells, k = cells.shape
    incidence = sp.csr_matrix((np.ones(cells.size), cells.ravel(), np.arange(0, cells.size + 1, k)),
                              shape=(n_cells, n_nodes))
    graph = (incidence.T @ incidence).tocsr()
    graph.data[:] = 1.0
    return graph


def mesh_fill(cells: np.ndarray, n_nodes: int, dofs_per_node: int = 3, fixed_nodes=None) -> Fill:
    """:class:`Fill` of a mesh's K by PARDISO's symbolic analysis of its node graph (module docstring).

    ``fixed_nodes``: nodes whose every DOF is supported (their rows leave K); other supports are not
    subtracted (the estimate stays an upper bound).
    """
    from pypardiso import PyPardisoSolver

    from .pardiso import _mkl_path

    graph = node_graph(cells, n_nodes)
    if fixed_nodes is not None and len(fixed_nodes):
        keep = np.ones(n_nodes, dtype=bool)
        keep[np.asarray(fixed_nodes, dtype=int)] = False
        graph = graph[keep][:, keep].tocsr()
        n_nodes = int(keep.sum())
    nnz_nodes = graph.nnz
    # Values only make the analysis's matrix a valid SPD one (diagonally dominant); phase 11 reads the pattern.
    graph.setdiag(np.asarray(graph.sum(axis=1)).ravel() + 1.0)
    upper = sp.triu(graph, format="csr")
    upper.sort_indices()
    _mkl_path()
    solver = PyPardisoSolver(mtype=2)
    solver.set_iparm(12, 0)
    solver.set_iparm(19, -1)  # report the factorisation's operations
    try:
        solver.set_phase(11)
        solver._call_pardiso(upper, np.zeros((n_nodes, 1)))
        nnz_l_nodes = int(solver.get_iparm(18))
        mflop_nodes = float(max(solver.get_iparm(19), 0))
    finally:
        solver.free_memory(everything=True)
    d = int(dofs_per_node)
    return Fill(n_dofs=d * n_nodes, nnz_K=d * d * nnz_nodes,
                nnz_L=d * d * (nnz_l_nodes - n_nodes) + d * (d + 1) // 2 * n_nodes,
                factor_mflop=d ** 3 * mflop_nodes)
