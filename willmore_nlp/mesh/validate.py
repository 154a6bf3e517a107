"""Validation of raw vertex/simplex arrays, with messages that name the problem."""

from __future__ import annotations

import numpy as np

from willmore_nlp.mesh.core import MeshError
from willmore_nlp.mesh.topology import scatter_sum, unique_rows


def validate_arrays(vertices: object, simplices: object, source: str) -> tuple[np.ndarray, np.ndarray]:
    """Check and convert the arrays of a mesh.

    Parameters
    ----------
    vertices : array_like, (N, m)
    simplices : array_like, (K, d + 1)
    source : str
        Named in every message.

    Returns
    -------
    V : (N, m) float64 array (a copy)
    S : (K, d + 1) int64 array (a copy)

    Raises
    ------
    MeshError
        Wrong shapes, non-integer or out-of-range indices, NaN/inf coordinates,
        unreferenced vertices, simplices with a repeated vertex or zero measure,
        duplicate simplices, and duplicate vertices (two vertices at the same position,
        up to :data:`DUPLICATE_RTOL` times the bounding-box size).
    """
    V = _vertex_array(vertices, source)
    S_raw = np.asarray(simplices)
    if S_raw.ndim != 2 or S_raw.shape[1] not in (2, 3):
        raise MeshError(
            f"{source}: simplices must have shape (K, 2) (segments) or (K, 3) (triangles), "
            f"got {S_raw.shape}"
        )
    if S_raw.shape[0] == 0:
        raise MeshError(f"{source}: the mesh has no simplices")
    if not np.issubdtype(S_raw.dtype, np.integer) and (
        not np.issubdtype(S_raw.dtype, np.number) or not np.all(np.isfinite(S_raw)) or np.any(S_raw != np.round(S_raw))
    ):
        raise MeshError(f"{source}: simplex indices must be integers")
    S = S_raw.astype(np.int64)
    N, nv = V.shape[0], S.shape[1]
    d, m = nv - 1, V.shape[1]
    if d == 2 and m != 3:
        raise MeshError(f"{source}: triangle surfaces must live in R^3, got vertices in R^{m}")
    out = np.flatnonzero((S < 0).any(axis=1) | (S >= N).any(axis=1))
    if out.size:
        raise MeshError(
            f"{source}: simplex {out[0]} has vertex index out of range [0, {N}): {S[out[0]].tolist()}"
        )
    used = np.zeros(N, dtype=bool)
    used[S.ravel()] = True
    unused = np.flatnonzero(~used)
    if unused.size:
        raise MeshError(
            f"{source}: vertex {unused[0]} is not used by any simplex "
            f"({unused.size} unreferenced vertices)"
        )
    Ss = np.sort(S, axis=1)
    rep = np.flatnonzero((np.diff(Ss, axis=1) == 0).any(axis=1))
    if rep.size:
        raise MeshError(f"{source}: simplex {rep[0]} repeats a vertex: {S[rep[0]].tolist()}")
    _, first, counts = unique_rows(Ss, return_index=True, return_counts=True)
    if np.any(counts > 1):
        i = int(first[np.argmax(counts > 1)])
        dup = np.flatnonzero((Ss == Ss[i]).all(axis=1))
        raise MeshError(f"{source}: simplices {dup[0]} and {dup[1]} are duplicates: {S[i].tolist()}")
    _check_positions(V, S, source)
    return V, S


def validate_vertices(vertices: object, simplices: np.ndarray, source: str) -> np.ndarray:
    """The vertex checks of :func:`validate_arrays` for new positions of an already validated topology.

    Parameters
    ----------
    vertices : array_like, (N, m)
    simplices : (K, d + 1) int64 array, validated (by :func:`validate_arrays`) for N vertices in R^m
    source : str

    Returns
    -------
    V : (N, m) float64 array (a copy)
    """
    V = _vertex_array(vertices, source)
    N = int(simplices.max()) + 1
    if V.shape[0] != N or (simplices.shape[1] == 3 and V.shape[1] != 3):
        raise MeshError(f"{source}: new vertices must have shape ({N}, {'3' if simplices.shape[1] == 3 else 'm'}) "
                        f"for the same simplices, got {V.shape}")
    _check_positions(V, simplices, source)
    return V


def _vertex_array(vertices: object, source: str) -> np.ndarray:
    """(N, m) float copy of ``vertices``: shape, finiteness and size checked."""
    if np.iscomplexobj(vertices):  # (numpy would drop the imaginary parts with a warning)
        raise MeshError(f"{source}: vertices are complex numbers; the coordinates must be real")
    try:
        V = np.array(vertices, dtype=float)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"{source}: vertices are not a numeric array ({exc})") from exc
    if V.ndim != 2 or V.shape[1] not in (2, 3):
        raise MeshError(f"{source}: vertices must have shape (N, 2) or (N, 3), got {V.shape}")
    if V.shape[0] == 0:
        raise MeshError(f"{source}: the mesh has no vertices")
    bad = np.flatnonzero(~np.isfinite(V).all(axis=1))
    if bad.size:
        raise MeshError(f"{source}: vertex {bad[0]} has a non-finite coordinate {V[bad[0]].tolist()}")
    big = np.flatnonzero((np.abs(V) > MAX_COORDINATE).any(axis=1))
    if big.size:
        raise MeshError(f"{source}: vertex {big[0]} has a coordinate beyond {MAX_COORDINATE:g} "
                        f"({V[big[0]].tolist()}): lengths and areas would overflow; rescale the mesh")
    return V


def _check_positions(V: np.ndarray, S: np.ndarray, source: str) -> None:
    """Degenerate simplices and duplicate vertices at the positions ``V`` ((N, m)) of simplices ``S``."""
    d = S.shape[1] - 1
    vol = simplex_volumes(V, S)
    scale = max(float(np.ptp(V, axis=0).max()), np.finfo(float).tiny)
    degenerate = np.flatnonzero(vol <= 1e-13 * scale**d)
    if degenerate.size:
        k = int(degenerate[0])
        closing = d == 1 and {int(S[k, 0]), int(S[k, 1])} == {0, len(V) - 1} and len(V) > 2
        hint = ("; the last point repeats the first (to rounding): remove it, a closed curve is closed automatically"
                if closing else "")  # (a common export habit; a new user's check)
        raise MeshError(f"{source}: segment {k} is degenerate (zero length): vertices {S[k, 0]} and {S[k, 1]}{hint}"
                        if d == 1 else f"{source}: simplex {k} is degenerate (zero area): vertices {S[k].tolist()}")
    dup_v = duplicate_vertices(V, DUPLICATE_RTOL * scale)
    if dup_v.size:
        i, j = (int(x) for x in dup_v[0])
        raise MeshError(
            f"{source}: vertices {i} and {j} are duplicates (both at {V[i].tolist()}; "
            f"{len(dup_v)} duplicate pair(s)): "
            + ("merge them, or perturb a curve that passes twice through a point" if d == 1
               else "merge them (unmerged copies split the surface along a seam)")
        )


MAX_COORDINATE = 1e150
"""Larger coordinates are refused: squared lengths (areas, distances) would overflow."""

DUPLICATE_RTOL = 1e-12
"""Two vertices closer than this times the largest bounding-box side are duplicates."""


def duplicate_vertices(V: np.ndarray, tol: float) -> np.ndarray:
    """Pairs of vertices at distance <= ``tol``.

    Parameters
    ----------
    V : (N, m) float array
    tol : float
        Distance below which two vertices count as one position (0 finds exact duplicates).

    Returns
    -------
    (P, 2) int array
        Index pairs ``i < j``, sorted.
    """
    from scipy.spatial import cKDTree

    pairs = cKDTree(V).query_pairs(max(tol, 0.0), output_type="ndarray")
    if pairs.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    pairs = np.sort(pairs, axis=1)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))].astype(np.int64)


def face_normals(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Unnormalised normals of the triangles ``S`` ((K, 3) int) at positions ``V`` ((N, 3)): the (K, 3) cross
    products (x1 - x0) x (x2 - x0), of length twice the area, oriented by the vertex order."""
    return np.cross(V[S[:, 1]] - V[S[:, 0]], V[S[:, 2]] - V[S[:, 0]])


def vertex_normals_of(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(N, 3) unit vertex normals of the triangles ``S`` ((K, 3) int) at ``V`` ((N, 3)): the normalised sums of
    the incident :func:`face_normals` (area weighted); zero rows at vertices of no triangle or a zero sum."""
    fn = face_normals(V, S)
    n = scatter_sum(V.shape[0], [(S[:, j], fn) for j in range(3)])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def simplex_volumes(V: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(K,) lengths (d = 1) or areas (d = 2) of the simplices ``S`` at vertex positions ``V``."""
    if S.shape[1] == 2:
        return np.linalg.norm(V[S[:, 1]] - V[S[:, 0]], axis=1)
    return 0.5 * np.linalg.norm(face_normals(V, S), axis=1)
