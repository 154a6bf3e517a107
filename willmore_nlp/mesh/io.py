"""Reading and writing meshes.

Surfaces: OBJ, PLY, OFF, STL through trimesh (no merging or repair: what is in the file is
what gets validated). Curves and any mesh: ``.npz`` with arrays ``vertices`` (N, m) and
``simplices`` (K, d+1). Curves also as text (``.txt``, ``.curve``, ``.xy``, ``.xyz``):

    # willmore_nlp curve            (comment lines start with '#')
    # closed                        (or '# open'; closed is the default)
    x y                             (one vertex per line: 2 or 3 numbers)
    ...

Vertices are joined in file order; a closed curve also joins the last vertex to the first.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import trimesh

from willmore_nlp.mesh.core import Mesh, MeshError

SURFACE_FORMATS = (".obj", ".ply", ".off", ".stl")
CURVE_FORMATS = (".txt", ".curve", ".xy", ".xyz")


def _read_curve_text(path: Path) -> Mesh:
    closed = True
    rows: list[list[float]] = []
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if not s:
                continue
            if s.startswith("#"):
                word = s[1:].strip().lower()
                if word == "open":
                    closed = False
                elif word == "closed":
                    closed = True
                continue
            parts = s.replace(",", " ").split()
            try:
                vals = [float(x) for x in parts]
            except ValueError as exc:
                raise MeshError(f"{path}:{lineno}: not a list of numbers: {s!r}") from exc
            if len(vals) not in (2, 3):
                raise MeshError(f"{path}:{lineno}: a vertex needs 2 or 3 coordinates, got {len(vals)}")
            if rows and len(vals) != len(rows[0]):
                raise MeshError(
                    f"{path}:{lineno}: vertex has {len(vals)} coordinates, earlier ones have {len(rows[0])}"
                )
            rows.append(vals)
    n = len(rows)
    if n < (3 if closed else 2):
        raise MeshError(f"{path}: a {'closed' if closed else 'open'} curve needs more vertices, got {n}")
    idx = np.arange(n)
    S = np.stack([idx, (idx + 1) % n], 1) if closed else np.stack([idx[:-1], idx[1:]], 1)
    return Mesh(np.array(rows), S, str(path))


def load_mesh(path: str | os.PathLike[str]) -> Mesh:
    """Read a mesh file (format from the extension); errors name the file and the problem."""
    p = Path(path)
    if not p.is_file():
        raise MeshError(f"{p}: no such file")
    ext = p.suffix.lower()
    if ext == ".npz":
        try:
            with np.load(p, allow_pickle=False) as data:
                missing = [k for k in ("vertices", "simplices") if k not in data.files]
                if missing:
                    raise MeshError(f"{p}: npz mesh lacks array(s) {missing}; it has {data.files}")
                return Mesh(data["vertices"], data["simplices"], str(p))
        except (OSError, ValueError) as exc:
            if isinstance(exc, MeshError):
                raise
            raise MeshError(f"{p}: not a readable npz file ({exc})") from exc
    if ext in CURVE_FORMATS:
        return _read_curve_text(p)
    if ext in SURFACE_FORMATS:
        try:
            tm = trimesh.load(p, force="mesh", process=False, validate=False)
        except Exception as exc:  # trimesh raises many types for malformed files
            raise MeshError(f"{p}: cannot be read as {ext[1:].upper()} ({type(exc).__name__}: {exc})") from exc
        if ext == ".stl":  # STL stores every triangle with its own corners: join equal positions
            tm.merge_vertices()
        faces = np.asarray(getattr(tm, "faces", np.zeros((0, 3))))
        if faces.size == 0:
            raise MeshError(f"{p}: no triangles found")
        return Mesh(np.asarray(tm.vertices), faces, str(p))
    raise MeshError(
        f"{p}: unknown mesh format {ext!r}; use one of "
        + ", ".join((*SURFACE_FORMATS, ".npz", *CURVE_FORMATS))
    )


def atomic_write(path: Path, write: callable) -> None:  # type: ignore[valid-type]
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def save_mesh(mesh: Mesh, path: str | os.PathLike[str]) -> None:
    """Write a mesh atomically: npz for anything, text for curves, trimesh formats for surfaces."""
    p = Path(path)
    ext = p.suffix.lower()
    if ext == ".npz":
        def w_npz(t: Path) -> None:
            with open(t, "wb") as fh:
                np.savez(fh, vertices=mesh.vertices, simplices=mesh.simplices)

        atomic_write(p, w_npz)
    elif ext in CURVE_FORMATS:
        if mesh.d != 1:
            raise MeshError(f"{p}: the text curve format holds curves only")
        order = _curve_order(mesh)
        header = "# willmore_nlp curve\n# " + ("closed" if mesh.is_closed else "open") + "\n"

        def w(t: Path) -> None:
            with open(t, "w", encoding="utf-8") as fh:
                fh.write(header)
                np.savetxt(fh, mesh.vertices[order], fmt="%.17g")

        atomic_write(p, w)
    elif ext in SURFACE_FORMATS:
        if mesh.d != 2:
            raise MeshError(f"{p}: {ext} holds triangle surfaces only")
        tm = trimesh.Trimesh(mesh.vertices, mesh.simplices, process=False)
        kw = {"digits": 17} if ext == ".obj" else {"encoding": "binary"} if ext == ".ply" else {}
        atomic_write(p, lambda t: tm.export(t, file_type=ext[1:], **kw))
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
