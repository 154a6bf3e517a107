"""Property-based tests of the curve and mesh file readers (hypothesis, bounded examples).

Round trips are exact for npz, text curves, OBJ and OFF; damaged files of every format give a
Mesh or a MeshError naming the file, never another exception.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from willmore_nlp import Mesh, MeshError
from willmore_nlp.mesh import shapes
from willmore_nlp.mesh.io import load_mesh, save_mesh

SETTINGS = settings(max_examples=80, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
ICO = shapes.icosphere(1)


@st.composite
def curves(draw: st.DrawFn) -> Mesh:
    """Star-shaped closed polygons or open polylines in R^2 or R^3 with arbitrary float coordinates."""
    n = draw(st.integers(3, 20))
    gaps = np.array(draw(st.lists(st.floats(0.2, 1.0), min_size=n, max_size=n)))
    angles = 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    radii = np.array(draw(st.lists(st.floats(1e-3, 1e3), min_size=n, max_size=n)))
    P = np.stack([radii * np.cos(angles), radii * np.sin(angles)], 1)
    if draw(st.booleans()):
        P = np.concatenate([P, np.array(draw(st.lists(st.floats(-1e3, 1e3), min_size=n, max_size=n)))[:, None]], 1)
    P = P + np.array(draw(st.lists(st.floats(-1e6, 1e6), min_size=P.shape[1], max_size=P.shape[1])))
    if draw(st.booleans()):
        return shapes.closed_curve(P)
    return shapes.open_curve(P)


@SETTINGS
@given(curves(), st.sampled_from([".txt", ".xy", ".npz"]))
def test_curve_round_trip_is_exact(mesh: Mesh, ext: str) -> None:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"c{ext}"
        save_mesh(mesh, p)
        back = load_mesh(p)
    assert back.vertices.tobytes() == mesh.vertices.tobytes()
    assert np.array_equal(back.simplices, mesh.simplices)
    assert back.is_closed == mesh.is_closed


@SETTINGS
@given(arrays(np.float64, (ICO.n_vertices,), elements=st.floats(0.5, 2.0)),
       st.floats(1e-3, 1e3), st.sampled_from([".obj", ".off", ".npz", ".ply"]))
def test_surface_round_trip(radii: np.ndarray, scale: float, ext: str) -> None:
    mesh = Mesh(ICO.vertices * radii[:, None] * scale, ICO.simplices)
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"s{ext}"
        save_mesh(mesh, p)
        back = load_mesh(p)
    assert np.array_equal(back.simplices, mesh.simplices)
    assert back.vertices.tobytes() == mesh.vertices.tobytes()


TOKENS = ["nan", "inf", "-1", "0", "1", "3", "1e400", "x", "", "1/2/3", "99999", "f", "v", "#", "OFF", "2.5", "-0"]
MUTATIONS = ["delete", "duplicate", "swap", "token", "truncate", "insert"]


def _mutate(text: str, data: st.DataObject) -> str:
    lines = text.splitlines()
    for _ in range(data.draw(st.integers(1, 3))):
        if not lines:
            break
        kind = data.draw(st.sampled_from(MUTATIONS))
        event(kind)
        i = data.draw(st.integers(0, len(lines) - 1))
        if kind == "delete":
            del lines[i]
        elif kind == "duplicate":
            lines.insert(i, lines[i])
        elif kind == "swap":
            j = data.draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif kind == "insert":
            lines.insert(i, " ".join(data.draw(st.lists(st.sampled_from(TOKENS), max_size=4))))
        elif kind == "token":
            tok = lines[i].split()
            if tok:
                tok[data.draw(st.integers(0, len(tok) - 1))] = data.draw(st.sampled_from(TOKENS))
            lines[i] = " ".join(tok)
        else:
            cut = "\n".join(lines)
            return cut[: data.draw(st.integers(0, len(cut)))]
    return "\n".join(lines) + "\n"


def _check_reader(p: Path) -> None:
    try:
        mesh = load_mesh(p)
    except MeshError as exc:
        assert str(exc).startswith(str(p)), exc
        event("rejected")
    else:
        assert np.all(np.isfinite(mesh.vertices))
        event("accepted")


@SETTINGS
@given(st.sampled_from([".obj", ".off", ".txt"]), st.data())
def test_damaged_text_files_give_mesh_or_mesh_error(ext: str, data: st.DataObject) -> None:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"m{ext}"
        save_mesh(shapes.regular_polygon(6) if ext == ".txt" else shapes.icosphere(0), p)
        p.write_text(_mutate(p.read_text(), data))
        _check_reader(p)


@settings(max_examples=40, deadline=None, database=None)
@given(st.sampled_from([".obj", ".off", ".txt", ".npz", ".ply", ".stl"]), st.data())
def test_damaged_binary_files_give_mesh_or_mesh_error(ext: str, data: st.DataObject) -> None:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"m{ext}"
        save_mesh(shapes.regular_polygon(6) if ext in (".txt", ".npz") else shapes.icosphere(0), p)
        raw = bytearray(p.read_bytes())
        how = data.draw(st.sampled_from(["truncate", "flip", "random"]))
        if how == "truncate":
            raw = raw[: data.draw(st.integers(0, len(raw)))]
        elif how == "flip":
            for _ in range(data.draw(st.integers(1, 8))):
                raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        else:
            raw = bytearray(data.draw(st.binary(max_size=300)))
        p.write_bytes(bytes(raw))
        _check_reader(p)
