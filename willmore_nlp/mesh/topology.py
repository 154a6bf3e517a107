"""Topology of simplicial meshes: boundary facets, manifoldness, orientation, components; and the index kernels
the mesh code shares (distinct values and rows, scatter sums)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from willmore_nlp.mesh.core import MeshError

if TYPE_CHECKING:
    from willmore_nlp.mesh.core import Mesh


def sorted_unique(a: np.ndarray) -> np.ndarray:
    """The sorted distinct values of the 1-D array ``a`` (``np.unique(a)``) by a sort: numpy >= 2.3 takes them
    from a hash table first, which on the millions of integer pattern keys of a step build is about twice as slow."""
    s = np.sort(a)
    return s[np.concatenate([s[:1] == s[:1], s[1:] != s[:-1]])]


def scatter_sum(n: int, parts: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Sums of values at indices: ``out[i] = sum of v[k] over (idx, v) in parts and k with idx[k] == i``.

    The values are added part by part in the order given, each part in its own order, exactly as successive
    ``np.add.at(out, idx, v)`` into zeros would add them (bitwise the same sums), by one ``np.bincount`` per
    column: np.add.at with (n, 3) rows was 6.5 times slower on the vertex normals of a 10,242-vertex sphere.

    Parameters
    ----------
    n : number of rows of the result (every index is below it)
    parts : (idx, v) pairs, idx (k,) int and v (k,) or (k, c) float (the same c in every part)

    Returns
    -------
    (n,) or (n, c) float array
    """
    idx = np.concatenate([np.asarray(i, dtype=np.int64).ravel() for i, _ in parts])
    if idx.size and not 0 <= int(idx.min()) <= int(idx.max()) < n:
        raise ValueError(f"scatter_sum: indices {int(idx.min())}..{int(idx.max())} outside 0..{n - 1}")
    vals = [np.asarray(v, float) for _, v in parts]
    if vals[0].ndim == 1:
        return np.bincount(idx, weights=np.concatenate(vals), minlength=n)
    W = np.concatenate(vals)
    out = np.empty((n, W.shape[1]))
    for c in range(W.shape[1]):
        out[:, c] = np.bincount(idx, weights=W[:, c], minlength=n)
    return out


def unique_rows(A: np.ndarray, *, return_index: bool = False, return_inverse: bool = False,
                return_counts: bool = False) -> Any:
    """``np.unique(A, axis=0, ...)`` of an integer array ``A`` ((n, c)): the same outputs in the same
    (lexicographic) order, from one int64 key per row.

    np.unique along an axis sorts the rows as structured records: 26 times slower on the 27,648 half-edges of a
    4,608-vertex torus (17 ms against 0.6 ms), which every mesh construction and light repair paid several times.
    Rows whose key would not fit in 62 bits go to np.unique itself.
    """
    A = np.asarray(A)
    flags = {"return_index": return_index, "return_inverse": return_inverse, "return_counts": return_counts}
    lo = int(A.min()) if A.size else 0
    base = int(A.max()) - lo + 1 if A.size else 1
    if A.size == 0 or base ** A.shape[1] > 2**62:
        return np.unique(A, axis=0, **flags)
    key = np.zeros(A.shape[0], dtype=np.int64)
    for j in range(A.shape[1]):
        key = key * base + (A[:, j].astype(np.int64) - lo)
    _, first, *rest = np.unique(key, return_index=True, return_inverse=return_inverse, return_counts=return_counts)
    out = (A[first], *((first,) if return_index else ()), *rest)
    return out[0] if len(out) == 1 else out


def unique_edges(S: np.ndarray) -> np.ndarray:
    """(E, 2) int array of the unique edges (sorted vertex pairs) of the simplices ``S`` ((K, d + 1))."""
    e = S if S.shape[1] == 2 else np.concatenate([S[:, [0, 1]], S[:, [1, 2]], S[:, [2, 0]]])
    return unique_rows(np.sort(e, axis=1))


def edge_lengths(V: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(E,) lengths of the edges ``edges`` ((E, 2)) at the positions ``V`` ((N, m))."""
    return np.linalg.norm(V[edges[:, 1]] - V[edges[:, 0]], axis=1)


def simplex_facets(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directed facets of every simplex and the simplex each belongs to.

    Returns
    -------
    F : (K * (d + 1), d) int array, facets with the orientation induced by their simplex
        (for curves: the end vertex of a segment as +1 facet and its start as -1 facet,
        encoded as a (K*2, 1) array with the sign in ``owner``'s companion; see below).
    owner : (K * (d + 1),) int array
    """
    K, nv = S.shape
    if nv == 2:
        F = np.concatenate([S[:, [0]], S[:, [1]]])
    else:
        F = np.concatenate([S[:, [0, 1]], S[:, [1, 2]], S[:, [2, 0]]])
    owner = np.tile(np.arange(K), nv)
    return F, owner


def edge_triangles(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two triangles of every interior edge of the triangles ``F`` ((K, 3)).

    Returns
    -------
    pairs : (E, 2) int array, the indices into F of the two triangles of each edge with exactly two
    ends : (E, 2) int array, the edge's vertices (sorted)
    """
    E, owner = simplex_facets(np.asarray(F))
    key = np.sort(E, axis=1)
    _, inv, counts = unique_rows(key, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    half = order[counts[inv[order]] == 2].reshape(-1, 2)
    return owner[half], key[half[:, 0]]


def boundary_facets(S: np.ndarray) -> np.ndarray:
    """(B, d) facets that belong to exactly one simplex (boundary of the mesh)."""
    F, _ = simplex_facets(S)
    key = np.sort(F, axis=1)
    _, inv, counts = unique_rows(key, return_inverse=True, return_counts=True)
    once = counts[inv.ravel()] == 1
    return F[once]


def _orientable(S: np.ndarray, n_vertices: int) -> bool:
    """Whether the edge-manifold triangles S ((K, 3) int) admit a consistent orientation (trimesh's winding repair
    on a copy succeeds)."""
    import trimesh

    t = trimesh.Trimesh(np.zeros((n_vertices, 3)), np.array(S), process=False)
    trimesh.repair.fix_winding(t)
    return bool(t.is_winding_consistent)


def check_manifold(mesh: Mesh) -> None:
    """Raise :class:`MeshError` unless ``mesh`` is a consistently oriented manifold.

    Curves: every vertex lies on at most two segments, and where it lies on two it is the
    end of one and the start of the other. Surfaces: every edge lies on at most two
    triangles, and an interior edge is traversed in opposite directions by its two triangles.
    """
    S, src = mesh.simplices, mesh.source
    if mesh.d == 1:
        deg = np.bincount(S.ravel(), minlength=mesh.n_vertices)
        bad = np.flatnonzero(deg > 2)
        if bad.size:
            raise MeshError(f"{src}: non-manifold curve: vertex {bad[0]} lies on {deg[bad[0]]} segments")
        for col, what in ((0, "start"), (1, "end")):
            c = np.bincount(S[:, col], minlength=mesh.n_vertices)
            bad = np.flatnonzero(c > 1)
            if bad.size:
                raise MeshError(
                    f"{src}: inconsistently oriented curve: vertex {bad[0]} is the {what} of "
                    f"{c[bad[0]]} segments"
                )
        return
    F, owner = simplex_facets(S)
    key = np.sort(F, axis=1)
    uniq, inv, counts = unique_rows(key, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    if np.any(counts > 2):
        e = uniq[np.argmax(counts > 2)]
        tris = owner[np.flatnonzero((key == e).all(axis=1))]
        raise MeshError(
            f"{src}: non-manifold surface: edge {e.tolist()} lies on {len(tris)} triangles "
            f"{tris.tolist()}"
        )
    directed, dcounts = unique_rows(F, return_counts=True)
    if np.any(dcounts > 1):
        e = directed[np.argmax(dcounts > 1)]
        tris = owner[np.flatnonzero((e == F).all(axis=1))]
        if _orientable(S, mesh.n_vertices):
            raise MeshError(
                f"{src}: inconsistently oriented surface: triangles {tris.tolist()} both traverse "
                f"edge {e.tolist()} in the same direction (the surface is orientable: orient its triangles "
                f"consistently, e.g. trimesh.repair.fix_winding)"
            )
        raise MeshError(
            f"{src}: non-orientable surface (like a Moebius strip): no orientation of its triangles is "
            f"consistent (triangles {tris.tolist()} both traverse edge {e.tolist()} in the same direction); "
            f"the flow needs an orientable surface"
        )
    # vertex manifoldness: the triangles around a vertex form one fan
    N = mesh.n_vertices
    K = mesh.n_simplices
    # triangles sharing an edge are adjacent; count fans per vertex via components of the
    # graph on (vertex, triangle) incidences linked through shared edges at that vertex
    shared = counts[inv] == 2
    e_idx = inv[shared]
    t = owner[shared]
    order = np.argsort(e_idx, kind="stable")
    pairs = t[order].reshape(-1, 2)
    edges_of_pairs = uniq[e_idx[order][::2]]
    inc_v = S.ravel()  # incidence i = (triangle i // 3, vertex S.ravel()[i])
    inc_key = np.repeat(np.arange(K, dtype=np.int64), 3) * N + inc_v
    order_key = np.argsort(inc_key)
    sorted_key = inc_key[order_key]

    def incidence(tri: np.ndarray, vert: np.ndarray) -> np.ndarray:
        return order_key[np.searchsorted(sorted_key, tri.astype(np.int64) * N + vert)]

    r = np.concatenate([incidence(pairs[:, 0], edges_of_pairs[:, j]) for j in range(2)])
    c = np.concatenate([incidence(pairs[:, 1], edges_of_pairs[:, j]) for j in range(2)])
    G = sp.coo_matrix((np.ones(r.size), (r, c)), shape=(inc_v.size, inc_v.size))
    _, labels = connected_components(G, directed=False)
    fans = np.bincount(unique_rows(np.stack([inc_v, labels], axis=1))[:, 0], minlength=N)
    bad = np.flatnonzero(fans > 1)
    if bad.size:
        raise MeshError(
            f"{src}: non-manifold surface: the triangles around vertex {bad[0]} form "
            f"{fans[bad[0]]} separate fans"
        )


def components(mesh: Mesh) -> tuple[int, np.ndarray]:
    """Connected components of the vertex graph.

    Returns
    -------
    n : int
        Number of components.
    labels : (N,) int array
        Component of each vertex.
    """
    return vertex_components(mesh.simplices, mesh.n_vertices)


def vertex_components(S: np.ndarray, N: int) -> tuple[int, np.ndarray]:
    """Connected components of the vertices of simplices ``S`` ((K, d+1)) among N vertices.

    Vertices on no simplex are components of their own. Returns ``(n, labels)`` as
    :func:`components`.
    """
    S = np.asarray(S)
    a, b = S[:, :-1].ravel(), S[:, 1:].ravel()
    A = sp.coo_matrix((np.ones(a.size), (a, b)), shape=(N, N))
    n, labels = connected_components(A, directed=False)
    return int(n), labels


def euler_characteristic(F: np.ndarray) -> int:
    """V - E + F of the triangles ``F`` ((K, 3) int), V counting the vertices they use (2 - 2 g for a closed
    connected surface of genus g)."""
    F = np.asarray(F)
    return int(sorted_unique(F.ravel()).size - unique_edges(F).shape[0] + F.shape[0])


def check_connected(mesh: Mesh, hint: str = "") -> None:
    """Raise :class:`MeshError` unless ``mesh`` is one connected curve or surface.

    Parameters
    ----------
    mesh : Mesh
    hint : str, optional
        Appended to the message (e.g. how to allow several components).
    """
    n, labels = components(mesh)
    if n == 1:
        return
    sizes = np.bincount(labels)
    kind = "curves" if mesh.d == 1 else "surfaces"
    shown = ", ".join(str(int(s)) for s in sizes[:6]) + (", ..." if n > 6 else "")
    raise MeshError(
        f"{mesh.source}: the mesh consists of {n} separate {kind} (vertex counts {shown}) where one "
        f"is expected" + (f"; {hint}" if hint else "")
    )
