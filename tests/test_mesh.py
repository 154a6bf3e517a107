"""Mesh value, validation basics, shapes, file round trips, reference Willmore energies."""

import numpy as np
import pytest

from willmore_nlp import Mesh, MeshError, willmore_energy
from willmore_nlp.analysis import fit_order
from willmore_nlp.geometry import enclosed_volume, measure, quality
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.io import load_mesh, save_mesh
from willmore_nlp.mesh.topology import scatter_sum, sorted_unique, unique_rows


def test_infers_dimensions_and_closedness() -> None:
    c = shapes.regular_polygon(10)
    assert (c.d, c.m, c.is_closed) == (1, 2, True)
    s = shapes.icosphere(1)
    assert (s.d, s.m, s.n_vertices, s.n_simplices, s.is_closed) == (2, 3, 42, 80, True)
    arc = Mesh(np.array([[0.0, 0], [1, 0], [2, 1]]), np.array([[0, 1], [1, 2]]))
    assert not arc.is_closed
    np.testing.assert_array_equal(arc.boundary_vertices, [0, 2])
    assert not c.vertices.flags.writeable


@pytest.mark.parametrize(
    ("V", "S", "match"),
    [
        (np.zeros((3, 4)), [[0, 1]], "shape"),
        ([[0, 0], [1, 0], [1, 1]], [[0, 1], [1, 5]], "out of range"),
        ([[0, 0], [1, np.nan], [1, 1]], [[0, 1], [1, 2], [2, 0]], "non-finite"),
        ([[0, 0], [1, 0], [1, 1]], [[0, 1], [1, 1], [2, 0]], "repeats a vertex"),
        ([[0, 0], [1, 0], [1, 1]], [[0, 1], [0, 1], [1, 2], [2, 0]], "duplicates"),
        ([[0, 0], [1, 0], [1, 0]], [[0, 1], [1, 2], [2, 0]], "degenerate"),
        ([[0, 0], [1, 0], [1, 1], [0, 1]], [[0, 1], [1, 2], [2, 0]], "not used"),
        ([[0, 0], [1, 0], [1, 1]], [[0, 1], [2, 1], [2, 0]], "oriented"),
        ([[0, 0], [1, 0], [1, 1], [0, 1], [2, 2]], [[0, 1], [0, 2], [0, 3], [1, 4]], "non-manifold"),
    ],
)
def test_validation_messages(V, S, match: str) -> None:
    with pytest.raises(MeshError, match=match):
        Mesh(np.asarray(V, float), np.asarray(S))


@pytest.mark.parametrize("flags", [{}, {"return_index": True}, {"return_inverse": True, "return_counts": True},
                                   {"return_index": True, "return_inverse": True, "return_counts": True}])
def test_unique_rows_and_sorted_unique_equal_numpy_unique(flags: dict) -> None:
    rng = np.random.default_rng(3)
    arrays = [rng.integers(-3, 5, (200, 2)), rng.integers(0, 4, (60, 3)), rng.integers(0, 9, (30, 1)),
              rng.integers(0, 2**40, (40, 2)),  # keys beyond 62 bits: numpy's own path
              np.zeros((0, 2), dtype=np.int64), shapes.torus(1.0, 0.5, 12, 6).simplices[:, [0, 1]]]
    for A in arrays:
        ours = unique_rows(A, **flags)
        ref = np.unique(A, axis=0, **flags)
        ours, ref = (ours, ref) if flags else ((ours,), (ref,))
        assert len(ours) == len(ref)
        for a, b in zip(ours, ref, strict=True):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b.reshape(a.shape))
        np.testing.assert_array_equal(sorted_unique(A[:, 0]), np.unique(A[:, 0]))


def test_scatter_sum_equals_successive_add_at_bit_for_bit() -> None:
    """scatter_sum adds as successive np.add.at calls into zeros would (the same sums to the last bit: the light
    repair's results must not move), for vectors and rows, repeated indices, several parts and empty parts."""
    rng = np.random.default_rng(5)
    S = shapes.torus(1.0, 0.5, 12, 6).simplices
    n = int(S.max()) + 3  # rows no index reaches stay 0
    for width in ((), (3,), (2,)):
        parts = [(S[:, j], rng.normal(size=(S.shape[0], *width)) * 10.0 ** rng.integers(-8, 8, S.shape[0]).reshape(
            -1, *(1,) * len(width))) for j in range(3)]
        parts.append((np.zeros(0, dtype=np.int64), np.zeros((0, *width))))
        ref = np.zeros((n, *width))
        for idx, v in parts:
            np.add.at(ref, idx, v)
        ours = scatter_sum(n, parts)
        assert ours.shape == ref.shape and ours.dtype == np.float64
        assert ours.tobytes() == ref.tobytes()
    with pytest.raises(ValueError, match=r"indices 0\.\.5 outside 0\.\.4"):
        scatter_sum(5, [(np.array([0, 5]), np.ones(2))])


def test_surface_orientation_and_manifold_errors() -> None:
    s = shapes.icosphere(1)
    F = s.simplices.copy()
    F[0] = F[0, ::-1]
    with pytest.raises(MeshError, match="oriented"):
        Mesh(s.vertices, F)
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0.5]], float)
    with pytest.raises(MeshError, match="non-manifold"):  # three triangles on edge (0, 1)
        Mesh(V, np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))


def test_torus_and_sphere_shapes_geometry() -> None:
    vol_err, area_err, hs = [], [], []
    for n in (16, 32, 64):
        t = shapes.torus(2.0, 0.5, 2 * n, n)
        hs.append(t.h)
        vol_err.append(abs(enclosed_volume(t) - 2 * np.pi**2 * 2.0 * 0.25))
        area_err.append(abs(measure(t) - 4 * np.pi**2 * 2.0 * 0.5))
    assert fit_order(hs, vol_err) == pytest.approx(2.0, abs=0.1)
    assert fit_order(hs, area_err) == pytest.approx(2.0, abs=0.1)
    s = shapes.icosphere(4)
    assert enclosed_volume(s) == pytest.approx(4 / 3 * np.pi, rel=5e-3)
    assert quality(s)["min_angle"] > 50


@pytest.mark.parametrize("ext", [".npz", ".obj", ".off", ".ply"])
def test_surface_round_trip(tmp_path, ext: str) -> None:
    s = shapes.torus(1.0, 0.4, 12, 6)
    save_mesh(s, tmp_path / f"t{ext}")
    s2 = load_mesh(tmp_path / f"t{ext}")
    np.testing.assert_array_equal(s2.simplices, s.simplices)
    assert s2.vertices.tobytes() == s.vertices.tobytes()  # (PLY too: it was written in single precision)
    if ext == ".ply":
        assert b"property double x" in (tmp_path / "t.ply").read_bytes()[:400]


@pytest.mark.parametrize("ext", [".obj", ".off"])
def test_a_straight_corner_away_from_the_first_is_read(tmp_path, ext: str) -> None:
    """A square face with a vertex in the middle of a side (where a neighbouring face ends), the straight corner not
    next to the first: read as a fan of three triangles of positive area covering the square."""
    V = "0 0 0\n1 0 0\n2 0 0\n2 2 0\n0 2 0\n"
    p = tmp_path / f"pent{ext}"
    if ext == ".obj":
        p.write_text("".join(f"v {row}\n" for row in V.splitlines()) + "f 4 5 1 2 3\n")
    else:
        p.write_text(f"OFF\n5 1 0\n{V}5 3 4 0 1 2\n")
    m = load_mesh(p)
    areas = 0.5 * np.linalg.norm(np.cross(*(m.vertices[m.simplices[:, k]] - m.vertices[m.simplices[:, 0]]
                                            for k in (1, 2))), axis=1)
    assert m.n_simplices == 3 and areas.min() > 0.4 and areas.sum() == pytest.approx(4.0)


def test_a_headerless_curve_file_is_read_when_it_is_a_sampled_curve(tmp_path) -> None:
    """A curve file without '# closed' is checked for being a sampled curve (io.POINT_CLOUD_TURN): a 24-gon with
    noise (median turn 15 degrees) and a 3D trefoil of 100 points are read; their points shuffled are refused, and
    read again with '# closed' before them."""
    rng = np.random.default_rng(0)
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    polygon = np.c_[np.cos(t), np.sin(t)] * (1 + 0.02 * rng.standard_normal(24))[:, None]
    s = np.linspace(0, 2 * np.pi, 100, endpoint=False)
    trefoil = np.c_[np.sin(s) + 2 * np.sin(2 * s), np.cos(s) - 2 * np.cos(2 * s), -np.sin(3 * s)]
    for name, P in (("polygon.xy", polygon), ("trefoil.xyz", trefoil)):
        p = tmp_path / name
        np.savetxt(p, P)
        assert load_mesh(p).n_vertices == len(P)
        np.savetxt(p, rng.permutation(P))
        with pytest.raises(MeshError, match="not a sampled curve"):
            load_mesh(p)
        p.write_text("# closed\n" + p.read_text())
        assert load_mesh(p).is_closed


def test_curve_file_open_and_closed_markers(tmp_path) -> None:
    """A comment whose first word is 'open' or 'closed' (any case, then the line's end, a space or punctuation) marks
    the curve (found by a new-user check: '# open curve' was an ordinary comment and a semicircle was closed by a
    chord); 'opened', 'open_curve' and 'closedness' are ordinary comments (closed, the default)."""
    t = np.linspace(0, np.pi, 21)
    semicircle = "".join(f"{np.cos(a):.17g} {np.sin(a):.17g}\n" for a in t)
    p = tmp_path / "c.txt"
    for comment, closed in (("# open", False), ("# open curve", False), ("# open: clamped", False), ("#OPEN", False),
                            ("#  Open-ended", False), ("# closed", True), ("# Closed.", True),
                            ("# closed (a cell)", True), ("# opened by hand", True), ("# open_curve", True),
                            ("# closedness", True), ("# the curve is open", True)):
        p.write_text(f"# willmore_nlp curve\n{comment}\n{semicircle}")
        assert load_mesh(p).is_closed is closed, comment
    p.write_text("# open\n# CLOSED\n" + semicircle)
    with pytest.raises(MeshError, match=r"c\.txt:2: .# closed. contradicts '# open' on line 1"):
        load_mesh(p)


def test_collinear_closed_curves_are_refused_and_thin_ones_read(tmp_path) -> None:
    """A closed curve whose vertices all lie on a line (a segment, back and forth along a line, in R^2 or R^3) is
    refused when read (found by a new-user check: it was called clockwise with "signed enclosed area 0" and failed in
    the solver); a 40-gon ellipse 1e-6 as wide as long is read, and so is an open curve along a line."""
    s = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    for name, P in (("thin.txt", np.c_[np.cos(s), 1e-6 * np.sin(s)]),
                    ("thin.npz", np.c_[1e3 + np.cos(s), 1e-6 * np.sin(s), np.cos(s)])):
        save_mesh(shapes.closed_curve(P), tmp_path / name)
        assert load_mesh(tmp_path / name).n_vertices == 40
    line = np.array([0.0, 1.0, 2.0, 1.5, 0.5])[:, None] * [[1.0, -3.0, 0.1]]
    (tmp_path / "line.xyz").write_text("".join(f"{x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in line))
    with pytest.raises(MeshError, match=r"line\.xyz: a degenerate closed curve: all its 5 vertices lie on a line"):
        load_mesh(tmp_path / "line.xyz")
    (tmp_path / "line.xyz").write_text("# open\n" + "".join(f"{x:.17g} {-3 * x:.17g} 0\n" for x in (0, 0.5, 1, 1.5)))
    assert not load_mesh(tmp_path / "line.xyz").is_closed


def test_curve_text_round_trip(tmp_path) -> None:
    c = shapes.hypocycloid(30, 0.1)
    save_mesh(c, tmp_path / "c.txt")
    c2 = load_mesh(tmp_path / "c.txt")
    np.testing.assert_allclose(c2.vertices, c.vertices, rtol=0, atol=0)
    np.testing.assert_array_equal(c2.simplices, c.simplices)
    (tmp_path / "bad.txt").write_text("0 0\n1 0\n1 x\n")
    with pytest.raises(MeshError, match=r"bad.txt:3"):
        load_mesh(tmp_path / "bad.txt")


def test_willmore_energy_reference_values() -> None:
    """Circle pi/R and sphere 8 pi, each converging at second order."""
    for R in (0.5, 2.0):
        hs, errs = [], []
        for n in (32, 64, 128):
            c = shapes.regular_polygon(n, R)
            hs.append(c.h)
            errs.append(abs(willmore_energy(c) - np.pi / R))
        assert errs[-1] < 1e-3 * np.pi / R
        assert fit_order(hs, errs) == pytest.approx(2.0, abs=0.1)
    errs = [abs(willmore_energy(shapes.icosphere(s, 3.0)) - 8 * np.pi) for s in (2, 3, 4)]
    assert np.all(np.diff(errs) < 0) and errs[-1] < 0.02 * 8 * np.pi
    # k-fold circle: k pi / R
    k, n = 3, 90
    t = 2 * np.pi * k * np.arange(n) / n
    P = np.stack([np.cos(t), np.sin(t)], 1) * (1 + 1e-9 * np.arange(n))[:, None]  # distinct points
    S = np.stack([np.arange(n), (np.arange(n) + 1) % n], 1)
    assert willmore_energy(Mesh(P, S)) == pytest.approx(k * np.pi, rel=2e-3)


def test_with_vertices_checks_positions_and_shares_the_topology() -> None:
    """``with_vertices`` gives what the constructor gives (vertices, edges, h, boundary) without checking the
    topology again (its cached edges and boundary are shared), and refuses the same bad positions with the
    constructor's messages."""
    sphere = shapes.icosphere(2)
    cap = sphere.simplices[sphere.vertices[sphere.simplices].mean(axis=1)[:, 2] > -0.3]  # a sphere with a hole
    used, S = np.unique(cap, return_inverse=True)
    disk = Mesh(sphere.vertices[used], S.reshape(cap.shape))
    _ = disk.edges, disk.boundary_vertices
    V = disk.vertices * np.array([1.0, 0.5, 2.0]) + 0.1
    moved, fresh = disk.with_vertices(V), Mesh(V, disk.simplices)
    np.testing.assert_array_equal(moved.vertices, fresh.vertices)
    assert not moved.vertices.flags.writeable and moved.edges is disk.edges
    np.testing.assert_array_equal(moved.edges, fresh.edges)
    np.testing.assert_array_equal(moved.boundary_vertices, fresh.boundary_vertices)
    assert moved.h == fresh.h and moved.source == disk.source and not moved.is_closed
    W = V.copy()
    W[3] = np.inf
    with pytest.raises(MeshError, match="vertex 3 has a non-finite coordinate"):
        disk.with_vertices(W)
    W = V.copy()
    W[disk.simplices[5]] = W[disk.simplices[5][0]] + [[0, 0, 0], [1e-3, 0, 0], [2e-3, 0, 0]]
    with pytest.raises(MeshError, match="degenerate"):
        disk.with_vertices(W)
    with pytest.raises(MeshError, match="shape"):
        disk.with_vertices(V[:-1])



def test_the_area_of_a_closed_curve_in_r3_is_its_vector_area() -> None:
    """A closed curve in R^3 had the area of its x1-x2 projection (a turning trefoil's report drew it growing 22 ->
    116; a new user's check): now the norm of its vector area, the polygon's area n/2 R^2 sin(2 pi/n) in any plane
    (also a vertical one, whose projection has area 0), unchanged by rotations and translations; a plane curve in
    R^2 keeps its signed area."""
    c = shapes.regular_polygon(20, 1.5)
    exact = 10 * 1.5**2 * np.sin(2 * np.pi / 20)
    assert enclosed_volume(c) == pytest.approx(exact, rel=1e-13)
    assert enclosed_volume(shapes.closed_curve(c.vertices[::-1])) == pytest.approx(-exact, rel=1e-13)
    vertical = np.column_stack([c.vertices[:, 0], np.zeros(20), c.vertices[:, 1]])
    assert enclosed_volume(shapes.closed_curve(vertical)) == pytest.approx(exact, rel=1e-13)
    knot = np.array([[np.sin(s) + 2 * np.sin(2 * s), np.cos(s) - 2 * np.cos(2 * s), -np.sin(3 * s)]
                     for s in np.linspace(0, 2 * np.pi, 90, endpoint=False)])
    Q = np.linalg.qr(np.random.default_rng(4).standard_normal((3, 3)))[0]
    a = enclosed_volume(shapes.closed_curve(knot))
    assert a > 0 and enclosed_volume(shapes.closed_curve(knot @ Q.T + 3.0)) == pytest.approx(a, rel=1e-12)
