"""The :class:`Mesh` value: vertices and simplices of a polygonal curve or a triangle surface."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from willmore_nlp.errors import UserInputError


class MeshError(UserInputError):
    """A mesh failed validation; the message names the offending vertex, simplex or file."""


@dataclass(frozen=True, eq=False)
class Mesh:
    """A simplicial mesh: a polygonal curve (d = 1) or a triangulated surface (d = 2).

    Parameters
    ----------
    vertices : (N, m) float array
        Vertex positions in R^m, m = 2 or 3.
    simplices : (K, d + 1) int array
        Vertex indices of each segment (d = 1) or triangle (d = 2).
    source : str, optional
        Where the mesh came from (a file name), used in error messages.

    Notes
    -----
    The arrays are copied and made read-only. Construction validates shapes, indices,
    finiteness, degenerate and duplicate simplices; manifoldness and orientation are
    checked for every mesh (see :func:`willmore_nlp.mesh.topology.check_manifold`).
    """

    vertices: np.ndarray
    simplices: np.ndarray
    source: str = field(default="<array>", compare=False)

    def __post_init__(self) -> None:
        from willmore_nlp.mesh.validate import validate_arrays

        V, S = validate_arrays(self.vertices, self.simplices, self.source)
        V.setflags(write=False)
        S.setflags(write=False)
        object.__setattr__(self, "vertices", V)
        object.__setattr__(self, "simplices", S)
        from willmore_nlp.mesh.topology import check_manifold

        check_manifold(self)

    # -- sizes ---------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        """Number of vertices N."""
        return int(self.vertices.shape[0])

    @property
    def n_simplices(self) -> int:
        """Number of simplices K."""
        return int(self.simplices.shape[0])

    @property
    def m(self) -> int:
        """Ambient dimension (2 or 3)."""
        return int(self.vertices.shape[1])

    @property
    def d(self) -> int:
        """Intrinsic dimension: 1 for curves, 2 for surfaces."""
        return int(self.simplices.shape[1] - 1)

    # -- topology ------------------------------------------------------------------------
    @cached_property
    def boundary_facets(self) -> np.ndarray:
        """(B, d) int array: facets (vertices for curves, edges for surfaces) on one simplex only."""
        from willmore_nlp.mesh.topology import boundary_facets

        return boundary_facets(self.simplices)

    @cached_property
    def boundary_vertices(self) -> np.ndarray:
        """(nb,) sorted int array of the vertices on the boundary."""
        return np.unique(self.boundary_facets)

    @property
    def is_closed(self) -> bool:
        """True when the mesh has no boundary."""
        return self.boundary_facets.shape[0] == 0

    @cached_property
    def edges(self) -> np.ndarray:
        """(E, 2) int array of unique edges (sorted vertex pairs)."""
        from willmore_nlp.mesh.topology import unique_edges

        return unique_edges(self.simplices)

    def edge_lengths(self, vertices: np.ndarray | None = None) -> np.ndarray:
        """(E,) lengths of :attr:`edges` at ``vertices`` (default: the mesh's own)."""
        from willmore_nlp.mesh.topology import edge_lengths

        return edge_lengths(self.vertices if vertices is None else np.asarray(vertices), self.edges)

    @property
    def h(self) -> float:
        """Mean edge length, the grid size h used in the paper's step-size choices."""
        return float(np.mean(self.edge_lengths()))

    def with_vertices(self, vertices: np.ndarray) -> Mesh:
        """The same topology at new vertex positions.

        The positions are validated as by the constructor (finite, no degenerate simplex, no duplicate
        vertex); the topology, already checked (indices, manifoldness, orientation), is shared with its
        cached edges and boundary: no second check (about 1 s at 40,962 vertices, paid a few times a step).
        """
        from willmore_nlp.mesh.validate import validate_vertices

        V = validate_vertices(vertices, self.simplices, self.source)
        V.setflags(write=False)
        new = object.__new__(Mesh)  # the dataclass __init__ would check the topology again
        for name, value in (("vertices", V), ("simplices", self.simplices), ("source", self.source)):
            object.__setattr__(new, name, value)
        for name in ("boundary_facets", "boundary_vertices", "edges"):
            if name in self.__dict__:
                new.__dict__[name] = self.__dict__[name]
        return new

    def __repr__(self) -> str:
        kind = "curve" if self.d == 1 else "surface"
        closed = "closed" if self.is_closed else "with boundary"
        return (
            f"Mesh({kind} in R^{self.m}, {closed}, N={self.n_vertices}, "
            f"K={self.n_simplices}, source={self.source!r})"
        )
