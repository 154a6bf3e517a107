"""Reading and writing meshes.

Every reader validates what it reads (:class:`~willmore_nlp.mesh.core.Mesh`) and raises
:class:`~willmore_nlp.mesh.core.MeshError` only, with a message naming the file, the line
where the problem is (text formats) and the problem.

Formats
-------
``.obj``, ``.off``
    Read and written here (strict, line-numbered errors; 17 significant digits, so a
    round trip is exact). Convex polygons with more than three corners are split into a fan
    of triangles from their first corner; non-convex ones are refused (a fan would fold), and so are those with a
    straight corner next to the first (a fan triangle of zero area; straight corners elsewhere are read).
    Bytes that are not UTF-8 are allowed in ``#`` comments, and a leading byte-order mark is dropped (in curve
    files too). No merging or repair: what is in the file is what gets validated.
``.ply``, ``.stl``
    Through trimesh (STL stores every triangle with its own corners, so exactly equal positions
    are joined; PLY polygons are split into fans like OBJ ones, and non-convex ones are refused).
``.npz``
    Any mesh: arrays ``vertices`` (N, m) and ``simplices`` (K, d+1).
``.txt``, ``.curve``, ``.xy``, ``.xyz``
    Curves as text::

        # willmore_nlp curve            (comment lines start with '#')
        # closed                        (or '# open'; closed is the default)
        x y                             (one vertex per line: 2 or 3 numbers)
        ...

    A comment whose first word is ``open`` or ``closed``, in any case and followed by the end of the line, white
    space or punctuation (``# Open curve``, ``# open: clamped``), is the marker (``CURVE_MARKER``; ``# opened`` is
    an ordinary comment); it must come before the first vertex, and a file with both an open and a closed marker is
    refused. Vertices are joined in file order; a closed curve also joins the last vertex to the
    first (so the first vertex must not be repeated at the end), and one whose vertices all lie on a line (zero
    enclosed area and width) is refused. A file without a marker
    whose points do not look like a sampled curve (a point cloud) is refused (``POINT_CLOUD_TURN``).

Numbers are read as Python reads them, except that a ``_`` in a number (``1_0``, read as 10 by Python) is refused in
every text format.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from willmore_nlp.errors import IO_ERRNOS, UserInputError
from willmore_nlp.mesh.core import Mesh, MeshError
from willmore_nlp.mesh.validate import DUPLICATE_RTOL

SURFACE_FORMATS = (".obj", ".ply", ".off", ".stl")
CURVE_FORMATS = (".txt", ".curve", ".xy", ".xyz")

_OBJ_IGNORED = frozenset({
    "vt", "vn", "vp", "g", "o", "s", "mg", "usemtl", "mtllib", "l", "p", "lod", "bevel", "c_interp",
    "d_interp", "shadow_obj", "trace_obj", "maplib", "usemap", "cstype", "deg", "bmat", "step", "curv",
    "curv2", "surf", "parm", "trim", "hole", "scrv", "sp", "end", "con", "ctech", "stech", "call", "csh",
})
"""OBJ statements that carry nothing a triangle mesh needs; they are skipped."""


# -- helpers -------------------------------------------------------------------------------
def _read_text(path: Path) -> list[str]:
    """Lines of a UTF-8 text file (a leading byte-order mark, as some Windows editors write, is dropped); undecodable
    bytes are allowed in ``#`` comments only (a MeshError naming the line and byte elsewhere)."""
    head = _head(path)
    if b"\x00" in head:  # fail fast on a binary file, before reading all of it
        line = head[: head.index(b"\x00")].count(b"\n") + 1
        raise MeshError(f"{path}:{line}: not a text file (contains a NUL byte)")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MeshError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    if b"\x00" in data:
        line = data[: data.index(b"\x00")].count(b"\n") + 1
        raise MeshError(f"{path}:{line}: not a text file (contains a NUL byte)")
    lines = data.removeprefix(b"\xef\xbb\xbf").decode("utf-8", "surrogateescape").splitlines()  # (a BOM: editors')
    for lineno, line in enumerate(lines, start=1):
        code = line.split("#", 1)[0]
        bad = next((i for i, ch in enumerate(code) if "\udc80" <= ch <= "\udcff"), None)
        if bad is not None:
            raise MeshError(f"{path}:{lineno}: not a UTF-8 text file (byte 0x{ord(code[bad]) - 0xDC00:02x} in column "
                            f"{bad + 1})")
    return lines


SNIFF_BYTES = 1 << 16
"""How much of a file is read to recognise its format before it is read whole."""


def _head(path: Path, n: int = SNIFF_BYTES) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read(n)
    except OSError as exc:
        raise MeshError(f"{path}: cannot be read ({exc.strerror or exc})") from exc


def _sniff_trimesh(path: Path, ext: str) -> None:
    """Refuse a .ply/.stl that is not one before trimesh reads it whole (MeshError)."""
    head = _head(path)
    size = path.stat().st_size
    if ext == ".ply":
        if not head.startswith((b"ply\n", b"ply\r\n")):
            raise MeshError(f"{path}: not a PLY file (it does not start with the line 'ply')")
        if b"end_header" not in head:
            raise MeshError(f"{path}: not a PLY file (no 'end_header' in its first {SNIFF_BYTES} bytes)")
        return
    if size >= 84:
        n = int(np.frombuffer(head[80:84], dtype="<u4")[0])
        if size == 84 + 50 * n:
            return  # a binary STL of n triangles
    if head.lstrip().startswith(b"solid") and b"\x00" not in head:
        return  # ASCII STL
    if size < 84:
        raise MeshError(f"{path}: not an STL file ({size} bytes, shorter than a binary STL header)")
    raise MeshError(f"{path}: not a valid STL file: as binary STL its header promises {n} triangles "
                    f"(84 + 50 x {n} = {84 + 50 * n} bytes) but the file has {size} bytes (truncated?), and it "
                    f"is not ASCII STL ('solid ...')")


def _no_separators(tok: str, path: Path, lineno: int, what: str) -> None:
    """Refuse a number token with a '_' (Python's float and int read '1_0' as 10; no mesh format allows it)."""
    if "_" in tok:
        raise MeshError(f"{path}:{lineno}: {what}: {tok!r} is not a number (a '_' is not allowed in numbers)")


def _number(tok: str, path: Path, lineno: int, what: str) -> float:
    _no_separators(tok, path, lineno, what)
    try:
        v = float(tok)
    except ValueError as exc:
        raise MeshError(f"{path}:{lineno}: {what}: {tok!r} is not a number") from exc
    if not np.isfinite(v):
        raise MeshError(f"{path}:{lineno}: {what}: non-finite value {tok!r}")
    return v


def _integer(tok: str, path: Path, lineno: int, what: str) -> int:
    _no_separators(tok, path, lineno, what)
    try:
        return int(tok)
    except ValueError as exc:
        raise MeshError(f"{path}:{lineno}: {what}: {tok!r} is not an integer") from exc


def _fan(corners: Sequence[int]) -> list[list[int]]:
    return [[corners[0], corners[i], corners[i + 1]] for i in range(1, len(corners) - 1)]


def _check_convex(polygons: Sequence[tuple[Sequence[int], int | str]], V: np.ndarray, path: Path) -> None:
    """Refuse polygons (corners, where: a line number or e.g. "face 7") whose fan triangulation from the first corner
    would fold (a corner that turns the other way: not convex) or have a triangle of zero area (a straight corner next
    to the first; a straight corner elsewhere, e.g. where a neighbouring face ends on a side, is harmless)."""
    for corners, lineno in polygons:
        P = V[list(corners)]
        nxt = np.roll(P, -1, axis=0)
        normal = np.cross(P, nxt).sum(axis=0)  # Newell's normal of the polygon
        e = nxt - P
        turn = np.cross(np.roll(e, 1, axis=0), e) @ normal  # > 0 at every corner of a convex polygon, 0 where straight
        tol = 1e-12 * float(normal @ normal)
        reflex = np.flatnonzero(turn < -tol)
        straight = [k for k in (1, len(corners) - 1) if abs(turn[k]) <= tol]
        if reflex.size or not normal.any():
            where = f" (at its corner {reflex[0] + 1})" if reflex.size else " (it has no area)"
            raise MeshError(f"{path}:{lineno}: a face with {len(corners)} corners is not convex{where}; it would be "
                            "split into folded triangles: triangulate it in the file")
        if straight:
            raise MeshError(f"{path}:{lineno}: a face with {len(corners)} corners has a straight (180-degree) corner "
                            f"{straight[0] + 1} next to its first, so its fan from the first corner would have a "
                            "triangle of zero area: start the face at another corner or triangulate it in the file")


def _locate(exc: MeshError, vlines: Sequence[int], slines: Sequence[int]) -> str:
    """Append source line numbers to the vertex/simplex indices named in a validation message."""
    msg = str(exc)

    def vline(i: str) -> str:
        k = int(i)
        return f"{i} (line {vlines[k]})" if 0 <= k < len(vlines) else i

    def sline(i: str) -> str:
        k = int(i)
        return f"{i} (line {slines[k]})" if 0 <= k < len(slines) else i

    msg = re.sub(r"\bvertices (\d+) and (\d+)", lambda m: f"vertices {vline(m[1])} and {vline(m[2])}", msg)
    msg = re.sub(r"\bvertex (\d+)", lambda m: f"vertex {vline(m[1])}", msg)
    msg = re.sub(r"\b(simplices|segments) (\d+) and (\d+)",
                 lambda m: f"{m[1]} {sline(m[2])} and {sline(m[3])}", msg)
    msg = re.sub(r"\b(simplex|segment) (\d+)", lambda m: f"{m[1]} {sline(m[2])}", msg)
    msg = re.sub(r"\btriangles \[([\d, ]+)\]",
                 lambda m: "triangles [" + ", ".join(sline(x.strip()) for x in m[1].split(",")) + "]", msg)
    return msg


def _mesh(V: object, S: object, path: Path, vlines: Sequence[int], slines: Sequence[int]) -> Mesh:
    try:
        return Mesh(V, S, str(path))  # type: ignore[arg-type]
    except MeshError as exc:
        raise MeshError(_locate(exc, vlines, slines)) from exc


# -- readers -------------------------------------------------------------------------------
def _read_curve_text(path: Path) -> Mesh:
    closed = True
    marker: tuple[str, int] | None = None  # the '# open' or '# closed' line (save_mesh writes one), its line number
    rows: list[list[float]] = []
    lines: list[int] = []
    for lineno, line in enumerate(_read_text(path), start=1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            found = CURVE_MARKER.match(s[1:])
            if found:
                word = found[1].lower()
                if rows:
                    raise MeshError(f"{path}:{lineno}: '# {word}' must come before the first vertex")
                if marker and marker[0] != word:
                    raise MeshError(f"{path}:{lineno}: '# {word}' contradicts '# {marker[0]}' on line {marker[1]}: "
                                    "a curve is either open or closed; keep one of the two lines")
                closed, marker = word == "closed", (word, lineno)
            continue
        parts = s.replace(",", " ").split()
        vals = [_number(x, path, lineno, "vertex coordinate") for x in parts]
        if len(vals) not in (2, 3):
            raise MeshError(f"{path}:{lineno}: a vertex needs 2 or 3 coordinates, got {len(vals)}: {s!r}")
        if rows and len(vals) != len(rows[0]):
            raise MeshError(
                f"{path}:{lineno}: vertex has {len(vals)} coordinates, the one on line {lines[0]} has "
                f"{len(rows[0])}"
            )
        rows.append(vals)
        lines.append(lineno)
    n = len(rows)
    if n < (3 if closed else 2):
        raise MeshError(
            f"{path}: a{' closed' if closed else 'n open'} curve needs at least {3 if closed else 2} vertices, got {n}"
        )
    if closed and rows[0] == rows[-1]:
        raise MeshError(
            f"{path}:{lines[-1]}: the last vertex repeats the first (line {lines[0]}); a closed curve is "
            f"closed automatically: remove the last vertex"
        )
    if marker is None:
        _check_sampled(np.array(rows), closed, path)
    idx = np.arange(n)
    S = np.stack([idx, (idx + 1) % n], 1) if closed else np.stack([idx[:-1], idx[1:]], 1)
    seg_lines = lines if closed else lines[:-1]
    return _mesh(np.array(rows), S, path, lines, seg_lines)


CURVE_MARKER = re.compile(r"\s*(open|closed)(?!\w)", re.IGNORECASE)
"""A comment of a curve file whose first word is ``open`` or ``closed`` (any case; followed by the end of the line,
white space or punctuation: ``# open``, ``# Open curve``, ``# closed: a cell``) declares the curve open or closed;
``# opened``, ``# open_curve`` or ``# closedness`` are ordinary comments."""


POINT_CLOUD_TURN = 60.0
"""A curve file without '# open' / '# closed' whose vertices, joined in file order, turn by more than this many degrees
at the median corner (and has at least ``POINT_CLOUD_MIN`` of them) is refused as not a sampled curve: a point cloud
(``.xyz`` is also a point-cloud format) joined in file order turns by much more (measured: 500 random points on a
sphere 121 degrees, the 642 vertices of a trimesh icosphere 147), a curve resolved by its vertices by 360 / n for a
regular n-gon."""
POINT_CLOUD_MIN = 20
"""Fewest vertices for the test of ``POINT_CLOUD_TURN`` (a coarse polygon turns by more: 72 degrees for a pentagon)."""


def _check_sampled(P: np.ndarray, closed: bool, path: Path) -> None:
    """Refuse the vertices P (n, m) of a curve file without an '# open' / '# closed' line that do not look like a
    sampled curve (``POINT_CLOUD_TURN``)."""
    if len(P) < POINT_CLOUD_MIN:
        return
    e = np.diff(np.vstack([P, P[:1]]) if closed else P, axis=0)
    a, b = (np.roll(e, 1, axis=0), e) if closed else (e[:-1], e[1:])
    norms = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    ok = norms > 0  # (a repeated vertex is the validation's to name)
    turn = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a[ok], b[ok]) / norms[ok], -1.0, 1.0)))
    median = float(np.median(turn)) if turn.size else 0.0
    if median > POINT_CLOUD_TURN:
        raise MeshError(f"{path}: its {len(P)} points joined in file order turn by {median:.0f} degrees at the "
                        "median corner: not a sampled curve (a point cloud?). A curve file lists the vertices of one "
                        "polygon in order ('# closed' or '# open' before them reads it as it is); a surface needs "
                        "its triangles: .obj, .off, .ply, .stl or .npz")


def _check_encloses(mesh: Mesh, path: Path) -> Mesh:
    """``mesh``, unless it is a closed curve whose vertices all lie on a line (MeshError): back and forth along a
    segment, it encloses nothing and has no width, so it has no outside to flow to (it was read, called clockwise with
    "signed enclosed area 0" and failed in the solver). On a line means within the tolerance of duplicate vertices
    (:data:`~willmore_nlp.mesh.validate.DUPLICATE_RTOL` times the bounding box's largest side); a thin ellipse is
    read."""
    if mesh.d != 1 or not mesh.is_closed:
        return mesh
    P = mesh.vertices - mesh.vertices.mean(axis=0)
    direction = np.linalg.svd(P, full_matrices=False)[2][0]  # of the best-fitting line through the centroid
    width = float(np.linalg.norm(P - np.outer(P @ direction, direction), axis=1).max())
    if width <= DUPLICATE_RTOL * float(np.ptp(mesh.vertices, axis=0).max()):
        hint = " ('# open' before the vertices reads them as an open curve)" if path.suffix.lower() != ".npz" else ""
        raise MeshError(f"{path}: a degenerate closed curve: all its {mesh.n_vertices} vertices lie on a line (zero "
                        f"enclosed area and zero width); a closed curve must enclose a region{hint}")
    return mesh


def _read_obj(path: Path) -> Mesh:
    verts: list[list[float]] = []
    vlines: list[int] = []
    tris: list[list[int]] = []
    tlines: list[int] = []
    pending: list[tuple[int, int, int]] = []  # (triangle, corner, line) with a positive index to check later
    polygons: list[tuple[list[int], int]] = []  # faces with more than three corners, checked for convexity
    n_lines = 0
    for lineno, raw in enumerate(_read_text(path), start=1):
        s = raw.split("#", 1)[0].strip()
        if not s:
            continue
        tok = s.split()
        kw = tok[0]
        if kw == "v":
            if len(tok) - 1 not in (3, 4, 6, 7):
                raise MeshError(
                    f"{path}:{lineno}: a vertex needs 3 coordinates (x y z, optionally w or r g b), "
                    f"got {len(tok) - 1}: {s!r}"
                )
            verts.append([_number(x, path, lineno, "vertex coordinate") for x in tok[1:4]])
            for x in tok[4:]:
                _number(x, path, lineno, "vertex weight/colour")
            vlines.append(lineno)
        elif kw == "f":
            if len(tok) < 4:
                raise MeshError(f"{path}:{lineno}: a face needs at least 3 corners, got {len(tok) - 1}: {s!r}")
            corners: list[int] = []
            for t in tok[1:]:
                i = _integer(t.split("/", 1)[0], path, lineno, "face corner")
                if i == 0:
                    raise MeshError(f"{path}:{lineno}: face corner 0: OBJ indices start at 1")
                if i < 0:
                    j = len(verts) + i
                    if j < 0:
                        raise MeshError(
                            f"{path}:{lineno}: relative face index {i} points before the first vertex "
                            f"({len(verts)} vertices so far)"
                        )
                    corners.append(j)
                else:
                    corners.append(i - 1)
            if len(set(corners)) != len(corners):
                raise MeshError(f"{path}:{lineno}: face repeats a vertex: {s!r}")
            if len(corners) > 3:
                polygons.append((corners, lineno))
            for tri in _fan(corners):
                for c, v in enumerate(tri):
                    if v >= len(verts):
                        pending.append((len(tris), c, lineno))
                tris.append(tri)
                tlines.append(lineno)
        elif kw in _OBJ_IGNORED:
            if kw == "l":
                n_lines += 1
        else:
            raise MeshError(f"{path}:{lineno}: unknown OBJ statement {kw!r}")
    for t, c, lineno in pending:
        if tris[t][c] >= len(verts):
            raise MeshError(
                f"{path}:{lineno}: face index {tris[t][c] + 1} is out of range (the file has {len(verts)} vertices)"
            )
    if not tris:
        extra = f" (it has {n_lines} 'l' polyline statements: save curves as .npz or text)" if n_lines else ""
        raise MeshError(f"{path}: no faces ('f' statements) found{extra}")
    V = np.array(verts, dtype=float) if verts else np.zeros((0, 3))
    _check_convex(polygons, V, path)
    return _mesh(V, np.array(tris, dtype=np.int64), path, vlines, tlines)


def _read_off(path: Path) -> Mesh:
    rows: list[tuple[int, list[str]]] = []
    for lineno, raw in enumerate(_read_text(path), start=1):
        s = raw.split("#", 1)[0].strip()
        if s:
            rows.append((lineno, s.split()))
    if not rows:
        raise MeshError(f"{path}: empty file (expected an 'OFF' header)")
    lineno, head = rows[0]
    if not head[0].upper().endswith("OFF"):
        raise MeshError(f"{path}:{lineno}: missing 'OFF' header, found {head[0]!r}")
    variant = head[0].upper()
    if variant not in ("OFF", "COFF", "NOFF", "CNOFF", "STOFF", "STCOFF", "STNOFF", "STCNOFF"):
        raise MeshError(f"{path}:{lineno}: unsupported OFF variant {head[0]!r} (3-D OFF with optional "
                        f"colours, normals or texture coordinates only)")
    pos = 1
    counts = head[1:]
    if not counts:
        if len(rows) < 2:
            raise MeshError(f"{path}: the file ends after the header (expected vertex and face counts)")
        lineno, counts = rows[1]
        pos = 2
    if len(counts) not in (2, 3):
        raise MeshError(f"{path}:{lineno}: expected 'n_vertices n_faces [n_edges]', got {' '.join(counts)!r}")
    nv = _integer(counts[0], path, lineno, "vertex count")
    nf = _integer(counts[1], path, lineno, "face count")
    if nv < 0 or nf < 0:
        raise MeshError(f"{path}:{lineno}: negative vertex or face count")
    if len(rows) < pos + nv + nf:
        got_v = min(nv, len(rows) - pos)
        got_f = max(0, len(rows) - pos - nv)
        raise MeshError(
            f"{path}: the header (line {lineno}) promises {nv} vertices and {nf} faces, the file ends after "
            f"{got_v} vertices and {got_f} faces"
        )
    verts: list[list[float]] = []
    vlines: list[int] = []
    for lineno, tok in rows[pos : pos + nv]:
        if len(tok) < 3 or (variant == "OFF" and len(tok) != 3):
            raise MeshError(f"{path}:{lineno}: a vertex needs 3 coordinates, got {len(tok)}: {' '.join(tok)!r}")
        verts.append([_number(x, path, lineno, "vertex coordinate") for x in tok[:3]])
        vlines.append(lineno)
    tris: list[list[int]] = []
    tlines: list[int] = []
    polygons: list[tuple[list[int], int]] = []
    for lineno, tok in rows[pos + nv : pos + nv + nf]:
        k = _integer(tok[0], path, lineno, "face corner count")
        if k < 3 or len(tok) < k + 1:
            raise MeshError(f"{path}:{lineno}: a face needs a count >= 3 and that many indices: {' '.join(tok)!r}")
        corners = [_integer(x, path, lineno, "face index") for x in tok[1 : k + 1]]
        for c in corners:
            if not 0 <= c < nv:
                raise MeshError(f"{path}:{lineno}: face index {c} is out of range [0, {nv})")
        if len(set(corners)) != k:
            raise MeshError(f"{path}:{lineno}: face repeats a vertex: {' '.join(tok)!r}")
        if k > 3:
            polygons.append((corners, lineno))
        for tri in _fan(corners):
            tris.append(tri)
            tlines.append(lineno)
    if len(rows) > pos + nv + nf:
        lineno = rows[pos + nv + nf][0]
        raise MeshError(f"{path}:{lineno}: unexpected data after the {nf} faces the header promises")
    if not tris:
        raise MeshError(f"{path}: no faces found")
    V = np.array(verts, dtype=float) if verts else np.zeros((0, 3))
    _check_convex(polygons, V, path)
    return _mesh(V, np.array(tris, dtype=np.int64), path, vlines, tlines)


def _read_npz(path: Path) -> Mesh:
    with path.open("rb") as f:
        if f.read(4) != b"PK\x03\x04":  # (numpy's message for a text file named .npz spoke of unpickling it)
            raise MeshError(f"{path}: not an npz file (an npz file is a zip archive of numpy arrays; this one does not "
                            "begin like one): give the file the suffix of its format")
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in ("vertices", "simplices") if k not in data.files]
            if missing:
                raise MeshError(f"{path}: npz mesh lacks array(s) {missing}; it has {data.files}")
            V, S = data["vertices"], data["simplices"]
    except MeshError:
        raise
    except Exception as exc:  # np.load and zipfile raise many types for damaged archives
        raise MeshError(f"{path}: not a readable npz file ({type(exc).__name__}: {exc})") from exc
    return Mesh(V, S, str(path))


def _read_trimesh(path: Path) -> Mesh:
    import trimesh

    ext = path.suffix.lower()
    _sniff_trimesh(path, ext)
    try:
        tm = trimesh.load(path, force="mesh", process=False, validate=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise MeshError(f"{path}: cannot be read as {ext[1:].upper()} ({type(exc).__name__}: {exc})") from exc
    if ext == ".ply":  # (trimesh reads a truncated ASCII PLY's first rows silently: "unreferenced vertices" followed)
        for element, raw in tm.metadata.get("_ply_raw", {}).items():
            data = raw.get("data")
            got = len(next(iter(data.values()))) if isinstance(data, dict) and data else None
            if got is not None and isinstance(raw.get("length"), int) and got < raw["length"]:
                raise MeshError(f"{path}: the header promises {raw['length']} {element} rows, the file has {got} "
                                "(truncated?)")
    faces = np.asarray(getattr(tm, "faces", np.zeros((0, 3))))
    if faces.size == 0:
        with open(path, "rb") as fh:
            text_stl = ext == ".stl" and fh.read(5).lower() == b"solid"
            fh.seek(max(0, path.stat().st_size - 256))
            ended = b"endsolid" in fh.read().lower()
        raise MeshError(f"{path}: no triangles found" + (" (an ASCII STL without 'endsolid' at its end: truncated?)"
                                                         if text_stl and not ended else ""))
    V = np.asarray(tm.vertices)
    if ext == ".stl":  # STL stores every triangle with its own corners: join equal positions (exactly equal: trimesh's
        V, inverse = np.unique(V, axis=0, return_inverse=True)  # merge_vertices rounds to 1e-8, which joined the
        faces = inverse.reshape(-1)[faces]  # corners of a mesh 3e-8 wide)
    if ext == ".ply":
        _check_convex(_ply_polygons(tm), V, path)
    return Mesh(V, faces, str(path))


def _ply_polygons(tm: Any) -> list[tuple[list[int], str]]:
    """The faces of more than three corners of a PLY file as trimesh read it (it splits them into fans, as the OBJ and
    OFF readers do; a non-convex one then folds), with their number in the file; [] when the raw faces are not
    kept."""
    raw = tm.metadata.get("_ply_raw", {}).get("face", {}).get("data", {})
    if not isinstance(raw, dict):
        return []
    idx = next((raw[k] for k in ("vertex_indices", "vertex_index") if k in raw), None)
    if idx is None:
        return []
    rows = list(idx) if np.asarray(idx, dtype=object).ndim == 1 else list(np.asarray(idx))
    return [([int(i) for i in c], f"face {k}") for k, c in enumerate(rows) if len(c) > 3]


def load_mesh(path: str | os.PathLike[str]) -> Mesh:
    """Read a mesh file (format from the extension).

    Raises
    ------
    MeshError
        The only exception raised for a bad file; the message names the file, the line
        (text formats) and the problem.
    """
    p = Path(path)
    if p.is_dir():
        raise MeshError(f"{p}: is a directory, not a mesh file")
    if not p.is_file():
        raise MeshError(f"{p}: no such file")
    ext = p.suffix.lower()
    if ext == ".npz":
        return _check_encloses(_read_npz(p), p)
    if ext in CURVE_FORMATS:
        return _check_encloses(_read_curve_text(p), p)
    if ext == ".obj":
        return _read_obj(p)
    if ext == ".off":
        return _read_off(p)
    if ext in SURFACE_FORMATS:
        return _read_trimesh(p)
    raise MeshError(
        f"{p}: unknown mesh format {ext!r}; use one of "
        + ", ".join((*SURFACE_FORMATS, ".npz", *CURVE_FORMATS))
    )


# -- writers -------------------------------------------------------------------------------
def make_dirs(path: Path) -> None:
    """Make the folder ``path`` and its parents (an output folder the user named, or a file's); a path that cannot be
    made is the user's: :class:`UserInputError` naming the part of it in the way (a dangling symbolic link, a file
    where a folder must go, a folder that cannot be made there such as /proc/x). The environment's errors (a full
    disk, no permission) stay OSErrors (exit 74). (These read "dl: File exists" or ended as an internal error.)"""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if exc.errno in IO_ERRNOS:
            raise
        why = exc.strerror or str(exc)
        for part in reversed([path, *path.parents]) if exc.errno in (errno.ENOENT, errno.EEXIST, errno.ENOTDIR) else ():
            if part.is_symlink() and not part.exists():
                why = f"{part} is a symbolic link to {os.readlink(part)}, which does not exist"
                break
            if part.exists() and not part.is_dir():
                why = f"{part} is a file, where a folder must go"
                break
        raise UserInputError(f"{path}: cannot make this folder: {why}") from exc


def atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it into place.

    The temporary file is named ``.NAME.XXXX.SUFFIX`` (hidden, never matching ``NAME``); it is
    removed when ``write`` fails. SIGINT and SIGTERM are held back meanwhile (:func:`signals_deferred`), so that
    a signal whose handler raises (a run's second Ctrl-C) does so after the write, not between the temporary
    file's creation and its removal. A process killed meanwhile leaves at most such a stray temporary file,
    never a partial ``path``.
    """
    make_dirs(path.parent)
    hidden = str(path.parent / f".{path.name}.")
    with signals_deferred():
        try:
            try:
                fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
            except OSError as exc:  # a folder that takes no new files (/proc): the path's, not a bug
                if exc.errno in IO_ERRNOS:
                    raise
                raise UserInputError(f"{path}: cannot make a file in {path.parent}: {exc.strerror or exc}") from None
            try:
                os.fchmod(fd, 0o666 & ~_umask())  # mkstemp makes 0600: give the file the mode open() would
            finally:
                os.close(fd)
            try:
                write(Path(tmp))
                os.replace(tmp, path)
            finally:
                if os.path.exists(tmp):
                    os.unlink(tmp)
        except OSError as exc:  # named by the file asked for, not the temporary one (a read-only folder's message)
            if isinstance(exc.filename, str) and exc.filename.startswith(hidden):
                raise type(exc)(exc.errno, exc.strerror, str(path)) from None
            raise


@contextlib.contextmanager
def signals_deferred(signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)) -> Iterator[list[int]]:
    """``signals`` (SIGINT and SIGTERM) held back for the block: their handlers are replaced by one that notes the
    signal in the list the block is given, and on exit the old handlers are restored and every noted signal is
    raised again (so a handler that raises, a run's second Ctrl-C or Python's own KeyboardInterrupt, does so after
    the block; a block may read the list to stop early, as an IPOPT solve does). Only in the main thread (the only
    one that may set handlers; elsewhere a no-op). Blocking the signals with ``pthread_sigmask`` was not enough: a
    signal sent to the process is delivered to any thread that does not block it (tqdm's monitor, BLAS threads), and
    Python then runs the handler in the main thread at once.

    Found: a second SIGINT a few milliseconds after the first (tests/test_reliability.py, rapid double signals)
    once left a ``.status.json.XXXX.json`` temporary file behind (a full test run of 2026-11-28)."""
    noted: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield noted
        return

    def note(signum: int, frame: object) -> None:
        noted.append(signum)

    old = {s: signal.signal(s, note) for s in signals}
    try:
        yield noted
    finally:
        for s, handler in old.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)
        for s in noted:
            signal.raise_signal(s)


def _umask() -> int:
    """The process's umask (read by setting it and restoring it at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _text_writer(text: str) -> Callable[[Path], None]:
    def w(t: Path) -> None:
        with open(t, "w", encoding="utf-8") as fh:
            fh.write(text)

    return w


def _fmt_rows(A: np.ndarray, prefix: str = "") -> str:
    return "".join(prefix + " ".join(f"{x:.17g}" for x in row) + "\n" for row in A)


def save_mesh(mesh: Mesh, path: str | os.PathLike[str]) -> None:
    """Write a mesh atomically: npz for anything, text for curves, OBJ/OFF/PLY/STL for surfaces.

    npz, text curves, OBJ, OFF and PLY (binary, double precision) round-trip exactly through :func:`load_mesh`.
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext == ".npz":
        def w_npz(t: Path) -> None:
            with open(t, "wb") as fh:
                np.savez(fh, vertices=mesh.vertices, simplices=mesh.simplices)

        atomic_write(p, w_npz)
    elif ext in CURVE_FORMATS:
        if mesh.d != 1:
            raise MeshError(f"{p}: the text curve format holds curves only; a surface is written as "
                            f"{', '.join(SURFACE_FORMATS)} or .npz")
        order = _curve_order(mesh)
        header = "# willmore_nlp curve\n# " + ("closed" if mesh.is_closed else "open") + "\n"
        atomic_write(p, _text_writer(header + _fmt_rows(mesh.vertices[order])))
    elif ext in SURFACE_FORMATS:
        if mesh.d != 2:
            raise MeshError(f"{p}: {ext} holds triangle surfaces only; a curve is written as "
                            f"{', '.join(CURVE_FORMATS)} (a text curve) or .npz")
        if ext == ".obj":
            text = ("# willmore_nlp\n" + _fmt_rows(mesh.vertices, "v ")
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.simplices))
            atomic_write(p, _text_writer(text))
        elif ext == ".off":
            text = (f"OFF\n{mesh.n_vertices} {mesh.n_simplices} 0\n" + _fmt_rows(mesh.vertices)
                    + "".join(f"3 {a} {b} {c}\n" for a, b, c in mesh.simplices))
            atomic_write(p, _text_writer(text))
        elif ext == ".ply":  # meshio's binary PLY holds doubles (trimesh's singles: vertices off by 3e-8)
            import meshio

            ply = meshio.Mesh(mesh.vertices, [("triangle", mesh.simplices.astype(np.int32))])  # (PLY has no int64)
            atomic_write(p, lambda t: meshio.write(t, ply, file_format="ply", binary=True))
        else:
            import trimesh

            tm = trimesh.Trimesh(mesh.vertices, mesh.simplices, process=False)
            atomic_write(p, lambda t: tm.export(t, file_type=ext[1:]))
    else:
        raise MeshError(f"{p}: unknown mesh format {ext!r}")


def _curve_order(mesh: Mesh) -> np.ndarray:
    """Vertex order along a single-component curve (start vertex of an open curve first)."""
    S = mesh.simplices
    nxt = np.full(mesh.n_vertices, -1)
    nxt[S[:, 0]] = S[:, 1]
    has_prev = np.zeros(mesh.n_vertices, bool)
    has_prev[S[:, 1]] = True
    starts = np.flatnonzero(~has_prev)
    v = int(starts[0]) if starts.size else int(S[0, 0])
    order = [v]
    while len(order) < mesh.n_vertices:
        v = int(nxt[v])
        if v < 0 or v == order[0]:
            raise MeshError(f"{mesh.source}: the curve has several components; save it as .npz")
        order.append(v)
    return np.array(order)
