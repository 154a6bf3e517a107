"""Property-based tests of mesh validation (hypothesis, bounded examples)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from willmore_nlp import Mesh, MeshError
from willmore_nlp.geometry import measure
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.topology import check_connected, components
from willmore_nlp.mesh.validate import duplicate_vertices, simplex_volumes

SETTINGS = settings(max_examples=60, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow])


@st.composite
def raw_arrays(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """Arbitrary small vertex/simplex arrays: wrong shapes, NaN/inf, bad and repeated indices."""
    n = draw(st.integers(1, 7))
    m = draw(st.sampled_from([1, 2, 3, 4]))
    coord = st.sampled_from([0.0, 1.0, -1.0, 0.5, 2.0]) | st.floats(-10, 10) | st.sampled_from(
        [np.nan, np.inf, -np.inf, 1e-300])
    V = draw(arrays(np.float64, (n, m), elements=coord))
    k = draw(st.integers(0, 9))
    nv = draw(st.sampled_from([1, 2, 2, 3, 3, 4]))
    S = draw(arrays(np.int64, (k, nv), elements=st.integers(-1, n)))
    return V, S


BASES = [shapes.regular_polygon(5), shapes.regular_polygon(6, m=3), shapes.icosphere(0)]


@st.composite
def mutated_arrays(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """A valid small mesh with 0-2 random defects (a coordinate, an index, a removed, repeated,
    flipped or extra simplex, an extra vertex)."""
    base = draw(st.sampled_from(BASES))
    V, S = base.vertices.copy(), base.simplices.copy()
    for _ in range(draw(st.integers(0, 2))):
        kind = draw(st.sampled_from(["coord", "copy_vertex", "index", "drop", "repeat", "flip", "extra_vertex"]))
        i = draw(st.integers(0, len(S) - 1))
        if kind == "coord":
            V[draw(st.integers(0, len(V) - 1)), draw(st.integers(0, V.shape[1] - 1))] = draw(
                st.sampled_from([np.nan, np.inf, 0.0, 1.0]))
        elif kind == "copy_vertex":
            V[draw(st.integers(0, len(V) - 1))] = V[draw(st.integers(0, len(V) - 1))]
        elif kind == "index":
            S[i, draw(st.integers(0, S.shape[1] - 1))] = draw(st.integers(-1, len(V)))
        elif kind == "drop" and len(S) > 1:
            S = np.delete(S, i, axis=0)
        elif kind == "repeat":
            S = np.concatenate([S, S[i : i + 1]])
        elif kind == "flip":
            S[i] = S[i, ::-1]
        elif kind == "extra_vertex":
            V = np.concatenate([V, V[:1] + 0.5])
    return V, S


@SETTINGS
@given(raw_arrays() | mutated_arrays())
def test_arbitrary_arrays_give_a_valid_mesh_or_a_mesh_error(arrs: tuple[np.ndarray, np.ndarray]) -> None:
    V, S = arrs
    try:
        mesh = Mesh(V, S, "src")
    except MeshError as exc:
        assert str(exc).startswith("src: ")
        event(str(exc).split(":")[1].split()[0])  # the kind of defect found
        return
    event("accepted")  # whatever is accepted satisfies every invariant the flow relies on
    V, S = mesh.vertices, mesh.simplices
    assert mesh.m in (2, 3) and mesh.d in (1, 2) and (mesh.d == 1 or mesh.m == 3)
    assert np.all(np.isfinite(V))
    assert S.min() >= 0 and S.max() < len(V)
    assert np.array_equal(np.unique(S), np.arange(len(V)))
    Ss = np.sort(S, axis=1)
    assert np.all(np.diff(Ss, axis=1) > 0)
    assert len(np.unique(Ss, axis=0)) == len(S)
    assert np.all(simplex_volumes(V, S) > 0)
    assert duplicate_vertices(V, 0.0).size == 0
    if mesh.d == 1:
        assert np.bincount(S.ravel()).max() <= 2


@st.composite
def star_polygon(draw: st.DrawFn) -> np.ndarray:
    """Vertices of a star-shaped polygon around 0 (a valid closed curve), in R^2 or R^3."""
    n = draw(st.integers(3, 24))
    gaps = np.array(draw(st.lists(st.floats(0.2, 1.0), min_size=n, max_size=n)))
    angles = 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    radii = np.array(draw(st.lists(st.floats(0.5, 2.0), min_size=n, max_size=n)))
    P = np.stack([radii * np.cos(angles), radii * np.sin(angles)], 1)
    if draw(st.booleans()):
        P = np.concatenate([P, np.array(draw(st.lists(st.floats(-1, 1), min_size=n, max_size=n)))[:, None]], 1)
    return P


def _closed(n: int) -> np.ndarray:
    return np.stack([np.arange(n), (np.arange(n) + 1) % n], 1)


@SETTINGS
@given(star_polygon(), st.randoms(use_true_random=False))
def test_valid_curves_survive_relabelling_and_reject_each_defect(P: np.ndarray, rnd: object) -> None:
    n = len(P)
    S = _closed(n)
    mesh = Mesh(P, S)
    assert mesh.is_closed and components(mesh)[0] == 1
    L = measure(mesh)
    perm = np.array(rnd.sample(range(n), n))  # type: ignore[attr-defined]
    inv = np.argsort(perm)
    relabelled = Mesh(P[perm], inv[S][rnd.sample(range(n), n)])  # type: ignore[attr-defined]
    assert relabelled.is_closed and measure(relabelled) == pytest.approx(L, rel=1e-12)
    i = rnd.randrange(n)  # type: ignore[attr-defined]
    flipped = S.copy()
    flipped[i] = flipped[i, ::-1]
    with pytest.raises(MeshError, match="inconsistently oriented curve"):
        Mesh(P, flipped)
    opened = Mesh(P, np.delete(S, i, axis=0))
    assert len(opened.boundary_vertices) == 2
    with pytest.raises(MeshError, match="are duplicates"):
        Mesh(P, np.concatenate([S, S[i : i + 1]]))
    if n >= 4:
        j = (i + 2) % n
        Q = P.copy()
        Q[j] = Q[i]
        with pytest.raises(MeshError, match=r"vertices \d+ and \d+ are duplicates"):
            Mesh(Q, S)
    two = Mesh(np.concatenate([P, P + 10.0]), np.concatenate([S, S + n]))
    with pytest.raises(MeshError, match="2 separate curves"):
        check_connected(two)


ICO = shapes.icosphere(1)


@SETTINGS
@given(arrays(np.float64, (ICO.n_vertices,), elements=st.floats(0.7, 1.3)), st.integers(0, ICO.n_simplices - 1))
def test_perturbed_spheres_are_valid_and_each_defect_is_named(radii: np.ndarray, i: int) -> None:
    V = ICO.vertices * radii[:, None]
    F = ICO.simplices
    mesh = Mesh(V, F, "sphere")
    assert mesh.is_closed
    flipped = F.copy()
    flipped[i] = flipped[i, ::-1]
    with pytest.raises(MeshError, match=r"^sphere: inconsistently oriented surface: triangles \[.*\] both traverse"):
        Mesh(V, flipped, "sphere")
    holed = Mesh(V, np.delete(F, i, axis=0))
    assert len(holed.boundary_facets) == 3
    with pytest.raises(MeshError, match="is not used by any simplex"):
        Mesh(np.concatenate([V, [[5.0, 5.0, 5.0]]]), F)
    with pytest.raises(MeshError, match="non-finite"):
        W = V.copy()
        W[F[i, 0], 1] = np.nan
        Mesh(W, F)
    a, b = F[i, :2]
    W = V.copy()
    W[b] = W[a]
    with pytest.raises(MeshError, match=r"degenerate|duplicates"):
        Mesh(W, F)
    two = Mesh(np.concatenate([V, V + np.array([4.0, 0.0, 0.0])]), np.concatenate([F, F + len(V)]), "two")
    with pytest.raises(MeshError, match=r"^two: the mesh consists of 2 separate surfaces"):
        check_connected(two)
