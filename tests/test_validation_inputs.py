"""Malformed inputs through the CLI: one readable line naming file, line/field and problem; nothing written.

Every case runs ``willmore-nlp run ...`` in-process (plus two cases in a subprocess, for the
exit code and the absence of a traceback). Each asserts exit code 2, a single stderr line
``willmore-nlp: error: ...`` containing the expected fragments, and that the output directory
was not created.
"""

from __future__ import annotations

import subprocess
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from willmore_nlp import cli
from willmore_nlp.flow import StepSizeWarning, WillmoreFlow
from willmore_nlp.mesh import Mesh, shapes
from willmore_nlp.mesh.io import save_mesh

CLI = [sys.executable, "-m", "willmore_nlp.cli"]


def _circle_txt(n: int = 8) -> str:
    t = 2 * np.pi * np.arange(n) / n
    return "".join(f"{np.cos(a):.17g} {np.sin(a):.17g}\n" for a in t)


def _ico_obj(flip: int | None = None, extra: str = "") -> str:
    s = shapes.icosphere(0)
    F = s.simplices.copy()
    if flip is not None:
        F[flip] = F[flip, ::-1]
    return ("".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in s.vertices)
            + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F) + extra)


def _icosphere_part_obj(cut: float = -0.2) -> str:
    """An icosphere(2) cut above z = ``cut`` (-0.2: an open surface; -2: the whole sphere)."""
    s = shapes.icosphere(2)
    keep = s.vertices[s.simplices].mean(axis=1)[:, 2] > cut
    F = s.simplices[keep]
    used = np.unique(F)
    index = np.full(s.n_vertices, -1)
    index[used] = np.arange(used.size)
    return ("".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in s.vertices[used])
            + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in index[F]))


def _saved(d: Path, name: str, V: object, S: object) -> list[str]:
    save_mesh(Mesh(np.asarray(V, float), np.asarray(S)), d / name)
    return [str(d / name)]


def _slab(thickness: float) -> tuple[np.ndarray, np.ndarray]:
    """A 1 x 1 x ``thickness`` box subdivided three times (386 vertices, edges about 0.1)."""
    import trimesh

    box = trimesh.creation.box(extents=[1.0, 1.0, thickness]).subdivide().subdivide().subdivide()
    return np.asarray(box.vertices), np.asarray(box.faces)


def _npz(path: Path, **arrays: object) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def _write(name: str, content: str | bytes) -> Callable[[Path], list[str]]:
    """A case whose input is one file, run as the target."""

    def make(d: Path) -> list[str]:
        p = d / name
        if isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content, encoding="utf-8")
        return [str(p)]

    return make


def _npz_case(name: str, **arrays: object) -> Callable[[Path], list[str]]:
    def make(d: Path) -> list[str]:
        _npz(d / name, **arrays)
        return [str(d / name)]

    return make


def _two_circles(d: Path) -> list[str]:
    a, b = shapes.regular_polygon(8), shapes.regular_polygon(8, 0.5)
    V = np.concatenate([a.vertices, b.vertices + np.array([3.0, 0.0])])
    S = np.concatenate([a.simplices, b.simplices + 8])
    _npz(d / "two.npz", vertices=V, simplices=S)
    return [str(d / "two.npz")]


def _two_spheres(d: Path) -> list[str]:
    s = shapes.icosphere(0)
    V = np.concatenate([s.vertices, s.vertices + np.array([3.0, 0.0, 0.0])])
    F = np.concatenate([s.simplices, s.simplices + s.n_vertices])
    save_mesh_raw(d / "two.off", V, F)
    return [str(d / "two.off")]


def save_mesh_raw(p: Path, V: np.ndarray, F: np.ndarray) -> None:
    """An OFF file of arbitrary (unvalidated) arrays."""
    p.write_text(f"OFF\n{len(V)} {len(F)} 0\n" + "".join(" ".join(f"{x:.17g}" for x in v) + "\n" for v in V)
                 + "".join("3 " + " ".join(str(int(i)) for i in f) + "\n" for f in F))


def _seam(d: Path) -> list[str]:
    """An icosphere whose vertex 0 is split into two copies at the same position (an unmerged seam)."""
    s = shapes.icosphere(0)
    V = np.concatenate([s.vertices, s.vertices[:1]])
    F = s.simplices.copy()
    first = np.flatnonzero((F == 0).any(axis=1))[:2]
    F[first] = np.where(F[first] == 0, len(V) - 1, F[first])
    save_mesh_raw(d / "seam.off", V, F)
    return [str(d / "seam.off")]


def _bowtie(d: Path) -> list[str]:
    """Two triangle fans sharing only vertex 0."""
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0.5], [0, -1, 0.5]], float)
    (d / "bowtie.obj").write_text("".join(f"v {a} {b} {c}\n" for a, b, c in V) + "f 1 2 3\nf 1 4 5\n")
    return [str(d / "bowtie.obj")]


def _moebius(d: Path) -> list[str]:
    """A Moebius strip: 12 x 2 quads of the band, split into triangles, the last column glued with a half twist."""
    nu, nv = 12, 3
    u, w = np.meshgrid(np.linspace(0, 2 * np.pi, nu, endpoint=False), np.linspace(-0.3, 0.3, nv), indexing="ij")
    V = np.stack([(1 + w * np.cos(u / 2)) * np.cos(u), (1 + w * np.cos(u / 2)) * np.sin(u), w * np.sin(u / 2)], -1)
    F = []
    for i in range(nu):
        for j in range(nv - 1):
            i2 = (i + 1) % nu
            j2, j3 = (j, j + 1) if i2 else (nv - 1 - j, nv - 2 - j)  # the half twist
            a, b, c, e = i * nv + j, i * nv + j + 1, i2 * nv + j2, i2 * nv + j3
            F += [(a, c, b), (b, c, e)]
    (d / "band.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in V.reshape(-1, 3))
                                + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
    return [str(d / "band.obj")]


def _toml(text: str, name: str = "cfg.toml") -> Callable[[Path], list[str]]:
    def make(d: Path) -> list[str]:
        (d / "c.txt").write_text(_circle_txt(12))
        (d / name).write_text(text)
        return [str(d / name)]

    return make


def _circle_with(*sets: str) -> Callable[[Path], list[str]]:
    def make(d: Path) -> list[str]:
        out = ["circle", "--set", "n=12"]
        for s in sets:
            out += ["--set", s]
        return out

    return make


OBJ_BAD_INDEX = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"
CASES: list[tuple[str, Callable[[Path], list[str]], list[str]]] = [
    # -- curve text files --------------------------------------------------------------------
    ("curve-not-a-number", _write("c.txt", "0 0\n1 0\n1 x\n"), ["c.txt:3", "'x' is not a number"]),
    ("curve-4-coordinates", _write("c.txt", "0 0 0 0\n1 0 0 0\n0 1 0 0\n"),
     ["c.txt:1", "a vertex needs 2 or 3 coordinates, got 4"]),
    ("curve-mixed-dimension", _write("c.txt", "0 0\n1 0\n0 1 2\n"),
     ["c.txt:3", "vertex has 3 coordinates, the one on line 1 has 2"]),
    ("curve-nan", _write("c.txt", "0 0\nnan 0\n0 1\n"), ["c.txt:2", "non-finite value 'nan'"]),
    ("curve-inf", _write("c.txt", "0 0\n1 0\n0 -inf\n"), ["c.txt:3", "non-finite value '-inf'"]),
    ("curve-too-few", _write("c.txt", "# closed\n0 0\n1 0\n"),
     ["c.txt", "closed curve needs at least 3 vertices, got 2"]),
    ("curve-empty", _write("c.txt", ""), ["c.txt", "needs at least 3 vertices, got 0"]),
    ("curve-first-repeated", _write("c.txt", "0 0\n1 0\n0 1\n0 0\n"),
     ["c.txt:4", "the last vertex repeats the first (line 1)"]),
    ("curve-first-repeated-to-rounding", _write("c.txt", "1 0\n0 1\n-1 0\n0 -1\n1 -2.4e-16\n"),  # (a new user's)
     ["c.txt", "segment 4 (line 5) is degenerate", "the last point repeats the first (to rounding): remove it"]),
    ("curve-duplicate-vertex", _write("c.txt", "0 0\n1 0\n1 1\n0 1\n1 0\n2 -1\n"),
     ["c.txt", "vertices 1 (line 2) and 4 (line 5) are duplicates"]),
    ("curve-zero-length-segment", _write("c.txt", "0 0\n1 0\n1 0\n0 1\n"),
     ["c.txt", "segment 1 (line 2) is degenerate (zero length): vertices 1 (line 2) and 2 (line 3)"]),
    ("curve-binary", _write("c.txt", b"\x89PNG\r\n\x1a\n\xff\xfe"), ["c.txt:1", "not a UTF-8 text file"]),
    ("curve-late-open", _write("c.txt", "0 0\n1 0\n# open\n0 1\n"), ["c.txt:3", "must come before the first vertex"]),
    # -- npz --------------------------------------------------------------------------------
    ("npz-missing-array", _npz_case("m.npz", vertices=np.zeros((3, 2))), ["m.npz", "lacks array(s) ['simplices']"]),
    ("npz-corrupt", _write("m.npz", b"PK\x03\x04 this is not a zip archive"), ["m.npz", "not a readable npz file"]),
    ("npz-text", _write("m.npz", "0 0 0\n1 0 0\n"), ["m.npz: not an npz file (an npz file is a zip archive",
                                                 "give the file the suffix of its format"]),
    ("npz-unreferenced-vertex",
     _npz_case("m.npz", vertices=[[0, 0], [1, 0], [0, 1], [5, 5]], simplices=[[0, 1], [1, 2], [2, 0]]),
     ["m.npz", "vertex 3 is not used by any simplex"]),
    ("npz-index-out-of-range",
     _npz_case("m.npz", vertices=[[0, 0], [1, 0], [0, 1]], simplices=[[0, 1], [1, 2], [2, 7]]),
     ["m.npz", "simplex 2 has vertex index out of range [0, 3)"]),
    ("npz-wrong-dimension", _npz_case("m.npz", vertices=np.eye(4), simplices=[[0, 1], [1, 2], [2, 3], [3, 0]]),
     ["m.npz", "vertices must have shape (N, 2) or (N, 3), got (4, 4)"]),
    ("npz-triangles-in-plane", _npz_case("m.npz", vertices=[[0, 0], [1, 0], [0, 1]], simplices=[[0, 1, 2]]),
     ["m.npz", "triangle surfaces must live in R^3"]),
    ("npz-float-indices",
     _npz_case("m.npz", vertices=[[0, 0], [1, 0], [0, 1]], simplices=[[0, 1], [1, 2.5], [2, 0]]),
     ["m.npz", "simplex indices must be integers"]),
    ("npz-non-manifold-curve",
     _npz_case("m.npz", vertices=[[0, 0], [1, 0], [1, 1], [0, 1], [2, 2]], simplices=[[0, 1], [0, 2], [0, 3], [1, 4]]),
     ["m.npz", "non-manifold curve: vertex 0 lies on 3 segments"]),
    ("npz-flipped-segment",
     _npz_case("m.npz", vertices=[[0, 0], [1, 0], [1, 1], [0, 1]], simplices=[[0, 1], [2, 1], [2, 3], [3, 0]]),
     ["m.npz", "inconsistently oriented curve"]),
    ("npz-two-curves", _two_circles, ["two.npz", "2 separate curves", "where one is expected",
                                      "allow_components=true"]),
    # -- OBJ / OFF / PLY ----------------------------------------------------------------------
    ("obj-flipped-triangle", _write("s.obj", _ico_obj(flip=5)),
     ["s.obj", "inconsistently oriented surface: triangles", "(line 18)", "the surface is orientable",
      "trimesh.repair.fix_winding"]),
    ("obj-moebius-strip", _moebius, ["band.obj", "non-orientable surface (like a Moebius strip)",
                                     "needs an orientable surface"]),
    ("obj-non-manifold-edge", _write("s.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 0 -1 0.5\n"
                                     "f 1 2 3\nf 2 1 4\nf 1 2 5\n"),
     ["s.obj", "non-manifold surface: edge [0, 1] lies on 3 triangles"]),
    ("obj-bowtie-vertex", _bowtie, ["bowtie.obj", "non-manifold surface", "vertex 0 (line 1)", "2 separate fans"]),
    ("obj-index-out-of-range", _write("s.obj", OBJ_BAD_INDEX), ["s.obj:4", "face index 9 is out of range"]),
    ("obj-2d-vertex", _write("s.obj", "v 0 0\nv 1 0\nv 0 1\nf 1 2 3\n"),
     ["s.obj:1", "a vertex needs 3 coordinates", "got 2"]),
    ("obj-degenerate", _write("s.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"),
     ["s.obj", "simplex 0 (line 4) is degenerate (zero area)"]),
    ("obj-unknown-statement", _write("s.obj", "hello world\n"), ["s.obj:1", "unknown OBJ statement 'hello'"]),
    ("obj-duplicate-triangle", _write("s.obj", _ico_obj(extra="f 1 12 6\n")),
     ["s.obj", "simplices 0 (line 13) and 20 (line 33) are duplicates"]),
    ("obj-nan", _write("s.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n"), ["s.obj:2", "non-finite value 'nan'"]),
    ("off-seam-duplicate-vertices", _seam, ["seam.off", "vertices 0 (line 3) and 12 (line 15) are duplicates"]),
    ("off-two-surfaces", _two_spheres, ["two.off", "2 separate surfaces", "where one is expected"]),
    ("off-no-header", _write("s.off", "3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"), ["s.off:1", "missing 'OFF' header"]),
    ("off-truncated", _write("s.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n"),
     ["s.off", "promises 3 vertices and 1 faces, the file ends after 2 vertices"]),
    ("ply-junk", _write("s.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n2\n"),
     ["s.ply", "cannot be read as PLY"]),
    ("mesh-missing-file", lambda d: [str(d / "nothere.obj")], ["nothere.obj", "no such file"]),
    ("mesh-unknown-format", lambda d: [*_write("m.vtk", "# vtk DataFile\n")(d)[:0], "file", "--set",
                                       f"path={d / 'm.vtk'}"], ["m.vtk", "unknown mesh format '.vtk'"]),
    # -- configs ------------------------------------------------------------------------------
    ("toml-syntax", _toml('mesh = "c.txt"\nsteps = \n'), ["cfg.toml", "invalid TOML"]),
    ("toml-typo-key", _toml('mesh = "c.txt"\nmax_retires = 3\n'),
     ["cfg.toml", "unknown key 'max_retires'", "did you mean 'max_retries'?"]),
    ("toml-tau-zero", _toml('mesh = "c.txt"\ntau = 0.0\n'), ["cfg.toml", "tau must be a number > 0, got 0.0"]),
    ("toml-tau-string", _toml('mesh = "c.txt"\ntau = "fast"\n'),
     ["cfg.toml", "tau must be a finite number, got 'fast'"]),
    ("toml-lam-negative", _toml('mesh = "c.txt"\nlam = -1\n'), ["cfg.toml", "lam must be a number >= 0, got -1"]),
    ("toml-unknown-table", _toml('mesh = "c.txt"\n[solver]\nname = "x"\n'), ["cfg.toml", "unknown table [solver]"]),
    ("toml-mesh-and-problem", _toml('mesh = "c.txt"\nproblem = "circle"\n'),
     ["cfg.toml", "give either 'problem' or 'mesh'"]),
    ("toml-int-param-float", _toml('problem = "circle"\nn = 12.5\n'), ["cfg.toml", "n must be an integer, got 12.5"]),
    ("toml-ipopt-unknown", _toml('mesh = "c.txt"\n[ipopt]\nfoo = 1\n'),
     ["cfg.toml", "IPOPT option foo = 1: unknown option"]),
    ("toml-ipopt-bad-setting", _toml('mesh = "c.txt"\n[ipopt]\nmu_strategy = "bogus"\n'),
     ["cfg.toml", "mu_strategy = 'bogus': not a valid setting (valid: monotone, adaptive)"]),
    ("toml-missing-file", lambda d: [str(d / "none.toml")], ["none.toml", "no such config file"]),
    ("toml-mesh-bad", _toml('mesh = "bad.txt"\n'), ["bad.txt", "no such file"]),
    ("set-tau-tilde-zero", _circle_with("tau_tilde=0"), ["--set", "tau_tilde must be a number > 0, got 0"]),
    ("set-tau-negative", _circle_with("tau=-0.1"), ["--set", "tau must be a number > 0, got -0.1"]),
    ("set-lam-negative", _circle_with("lam=-2"), ["--set", "lam must be a number >= 0"]),
    ("set-no-equals", _circle_with("tau"), ["--set 'tau'", "expected key=value"]),
    ("set-max-retries", _circle_with("max_retries=-1"), ["--set", "max_retries must be an integer >= 0, got -1"]),
    ("set-min-angle", _circle_with("min_angle=75"), ["--set", "min_angle must be a number in [0, 60)"]),
    ("set-unknown-solver", _circle_with("solver=bfgs"), ["unknown solver 'bfgs'"]),
    ("set-bool", _circle_with("check_energy=maybe"), ["--set: check_energy must be true or false, got 'maybe'"]),
    ("unknown-problem", lambda d: ["spheroid"], ["unknown problem 'spheroid'"]),
    # -- found in the second reliability pass ---------------------------------------------------
    ("obj-concave-polygon", _write("s.obj", "v 0 0 0\nv 2 1 0\nv 0 2 0\nv 0.5 1 0\nf 1 2 3 4\n"),
     ["s.obj:5", "a face with 4 corners is not convex (at its corner 4)", "triangulate it"]),
    ("obj-straight-corner-next-to-the-first",
     _write("s.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 2 2 0\nv 0 2 0\nf 1 2 3 4 5\n"),
     ["s.obj:6", "a face with 5 corners has a straight (180-degree) corner 2 next to its first",
      "start the face at another corner"]),
    ("off-concave-polygon", _write("s.off", "OFF\n4 1 0\n0 0 0\n2 1 0\n0 2 0\n0.5 1 0\n4 0 1 2 3\n"),
     ["s.off:7", "is not convex"]),
    ("obj-latin1-outside-comment", _write("s.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\ng caf\xe9\nf 1 2 3\n"),
     ["s.obj:4", "not a UTF-8 text file (byte 0xe9 in column 6)"]),
    ("stl-truncated-binary", _write("s.stl", b"\0" * 80 + np.uint32(10).tobytes() + b"\0" * 300),
     ["s.stl", "header promises 10 triangles", "the file has 384 bytes (truncated?)"]),
    ("ply-zero-filled", _write("s.ply", b"\0" * 100_000), ["s.ply", "not a PLY file"]),
    ("obj-zero-filled", _write("s.obj", b"\0" * 100_000), ["s.obj:1", "not a text file (contains a NUL byte)"]),
    ("toml-huge", _toml('mesh = "c.txt"\n' + "#" * 1_100_000 + "\n"), ["cfg.toml", "is not a config file"]),
    # -- found by a new-user check (2026-11-30) ---------------------------------------------------
    ("set-radius-inf", _circle_with("R=inf"), ["--set: R must be a finite number, got 'inf'"]),
    ("set-radius-negative", _circle_with("R=-1"), ["regular_polygon: radius must be a finite number > 0, got -1.0"]),
    ("set-ipopt-linear-solver-not-built", _circle_with("ipopt.linear_solver=ma27"),
     ["IPOPT refused the options {'linear_solver': 'ma27'}", "not in this build?"]),
    ("npy-not-a-format", _write("plain.npy", b"\x93NUMPY"),
     ["plain.npy: not a supported mesh or config format (meshes: .curve, .npz, .obj"]),
    ("obj-and-set-path", lambda d: [*_write("s.obj", _ico_obj())(d), "--set", "path=other.obj"],
     ["s.obj: the mesh is given twice, as the target and as --set path=other.obj: give one"]),
    ("toml-mesh-and-path", _toml('mesh = "c.txt"\npath = "c.txt"\n'), ["cfg.toml: give either 'mesh' or 'path'"]),
    ("set-remesh-target-tiny",
     lambda d: [*_write("s.obj", _icosphere_part_obj(cut=-2.0))(d), "--set", "remesh_target=1e-4"],
     ["s.obj: remesh_target = 0.0001 would remesh the input (162 vertices", "more than refine_max_vertices = 50,000"]),
    ("obj-open-volume",
     lambda d: [*_write("cap.obj", _icosphere_part_obj())(d), "--set", "clamp=conormal", "--set", "volume=initial"],
     ["cap.obj: volume needs a closed curve in R^2 or a closed surface"]),
    ("ply-concave-polygon", _write("s.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\n"
                                   "property double y\nproperty double z\nelement face 1\n"
                                   "property list uchar int vertex_indices\nend_header\n0 0 0\n2 1 0\n0 2 0\n"
                                   "0.5 1 0\n4 0 1 2 3\n"),
     ["s.ply:face 0: a face with 4 corners is not convex (at its corner 4)"]),
    ("obj-far-from-origin", lambda d: _saved(d, "far.obj", shapes.icosphere(1).vertices + 1e5,
                                             shapes.icosphere(1).simplices),
     ["far.obj: the mesh lies 1e+05 from the origin, 5e+04 times its width", "move it to the origin"]),
    ("obj-thin-slab", lambda d: _saved(d, "slab.obj", *_slab(0.02)),
     ["slab.obj: the input mesh is below the mesh control's thresholds, and repairing it at its own edge length would "
      "change its shape (area 2.08 ->", "features thinner than its edges", "--set input_repair=false"]),
    ("obj-clamped-without-free-vertex",
     lambda d: [*_saved(d, "grid.obj", np.c_[np.mgrid[0:3, 0:3].reshape(2, -1).T, np.zeros(9)],
                        [[0, 3, 4], [0, 4, 1], [1, 4, 5], [1, 5, 2], [3, 6, 7], [3, 7, 4], [4, 7, 8], [4, 8, 5]]),
                "--set", "clamp=conormal"],
     ["grid.obj: no free vertex: every one of the 9 vertices lies in the clamped outer strip", "use a finer mesh"]),
    ("xyz-point-cloud", _write("cloud.xyz", "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in
                                                    np.random.default_rng(1).standard_normal((30, 3)))),
     ["cloud.xyz: its 30 points joined in file order turn by", "not a sampled curve (a point cloud?)",
      "'# closed' or '# open' before them reads it as it is"]),
    ("set-n-huge", _circle_with("n=1e9"),
     ["regular_polygon: n = 1,000,000,000 would make 1,000,000,000 vertices, more than 2,000,000"]),
    ("set-torus-grid-huge", lambda d: ["torus", "--set", "n_major=100000", "--set", "n_minor=100000"],
     ["torus: n_major = 100,000 x n_minor = 100,000 would make 10,000,000,000 vertices"]),
    # (these three were built until the memory ran out: sphere 12 GB before step 1; a new-user check, 2026-11-30)
    ("set-sphere-subdivisions-huge", lambda d: ["sphere", "--set", "subdivisions=9"],
     ["icosphere: subdivisions = 9 would make 2,621,442 vertices, more than 2,000,000"]),
    ("set-sphere-cap-rings-huge", lambda d: ["sphere_cap", "--set", "rings=100000"],
     ["disk: rings = 100,001 would make 30,000,900,007 vertices, more than 2,000,000"]),
    ("set-surface-blending-huge", lambda d: ["surface_blending", "--set", "n_around=100000", "--set", "n_gap=100000"],
     ["cylinder: n_around = 100,000 x n_along + 1 =", "vertices, more than 2,000,000"]),
    ("ply-truncated-ascii", _write("t.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\n"
                                   "property double y\nproperty double z\nelement face 2\n"
                                   "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
                                   "0 0 1\n3 0 1 2\n"),
     ["t.ply: the header promises 2 face rows, the file has 1 (truncated?)"]),
    ("stl-truncated-ascii", _write("t.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"),
     ["t.stl: no triangles found (an ASCII STL without 'endsolid' at its end: truncated?)"]),
    ("set-vesicle-reduced-volume-tiny", lambda d: ["vesicle", "--set", "reduced_volume=0.01", "--set", "start=prolate"],
     ["parameter reduced_volume: must be in [0.132, 1) for the prolate start at subdivisions=3 (642 vertices), "
      "got 0.01"]),
    ("set-vesicle-reduced-volume-below-the-root-finders-reach", lambda d: ["vesicle", "--set", "reduced_volume=1e-9"],
     ["parameter reduced_volume: must be in [0.0817, 1) for the oblate start at subdivisions=3 (642 vertices), got "
      "1e-09: below it the start mesh folds", "more subdivisions reach lower (0.0411 at subdivisions=4)"]),
    ("set-vesicle-subdivisions-zero", lambda d: ["vesicle", "--set", "subdivisions=0"],
     ["parameter subdivisions: must be in [1, 7]"]),
    ("set-vesicle-volume", lambda d: ["vesicle", "--set", "volume=3"],
     ["volume is set by the problem's parameters; set reduced_volume instead"]),
    # -- found by a new-user check (2026-12-01) ---------------------------------------------------
    ("curve-open-and-closed", _write("c.txt", "# open curve\n# Closed.\n0 0\n1 0\n0 1\n"),
     ["c.txt:2: '# closed' contradicts '# open' on line 1: a curve is either open or closed"]),
    ("curve-on-a-segment", _write("c.txt", "".join(f"{x / 9:.17g} {2 * x / 9:.17g}\n" for x in range(10))),
     ["c.txt: a degenerate closed curve: all its 10 vertices lie on a line (zero enclosed area and zero width)",
      "'# open' before the vertices"]),
    ("curve-back-and-forth", _write("c.xyz", "0 0 0\n1 1 1\n2 2 2\n1.5 1.5 1.5\n0.5 0.5 0.5\n"),
     ["c.xyz: a degenerate closed curve: all its 5 vertices lie on a line"]),
    ("npz-curve-on-a-line", _npz_case("m.npz", vertices=[[0, 0], [1, 0], [3, 0], [2, 0]],
                                      simplices=[[0, 1], [1, 2], [2, 3], [3, 0]]),
     ["m.npz: a degenerate closed curve: all its 4 vertices lie on a line"]),
    ("curve-digit-separator", _write("c.txt", "0 0\n1_0 0\n0 1\n"),
     ["c.txt:2: vertex coordinate: '1_0' is not a number (a '_' is not allowed in numbers)"]),
    ("obj-digit-separator", _write("s.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0_5\nf 1 2 3\n"),
     ["s.obj:3: vertex coordinate: '0_5' is not a number"]),
    ("off-digit-separator", _write("s.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 0_2\n"),
     ["s.off:6: face index: '0_2' is not a number"]),
    # (the solver's own refusal ended "use volume=None", which --set cannot give and the problem refuses)
    ("set-vesicle-solver-without-constraints", lambda d: ["vesicle", "--set", "solver=lbfgs"],
     ["solver lbfgs cannot handle the problem's volume and area constraints (set by reduced_volume; it has no outer "
      "equality constraints): use one of gd, ipopt, newton-krylov, sqp"]),
    ("set-vesicle-fallback-solver-without-constraints", lambda d: ["vesicle", "--set", "fallback_solver=semi-implicit"],
     ["fallback_solver semi-implicit cannot handle the problem's volume and area constraints"]),
    ("set-volume-far-from-the-mesh",
     lambda d: [*_saved(d, "e.obj", shapes.icosphere(3).vertices * [1.0, 1.0, 1.6], shapes.icosphere(3).simplices),
                "--set", "volume=3", "--set", "area=initial"],
     ["e.obj: volume/area targets far from the initial mesh's own (volume 3 (its own 6.6", "smallest angle of 0.5",
      "start from a mesh nearer the targets"]),
    # (targets beyond the isoperimetric inequality failed only in the restoration: "cannot be moved onto the outer
    # constraints (... relative residual 2.005e+00)")
    ("set-volume-area-beyond-the-isoperimetric-inequality",
     lambda d: ["sphere", "--set", "volume=8", "--set", "area=19"],
     ["icosphere(3): volume = 8 and area = 19 are impossible targets: the isoperimetric inequality 36 pi V^2 <= A^3 "
      "(equal only for a round sphere, which no mesh is) bounds the reduced volume 6 sqrt(pi) V / A^1.5 by 1, and "
      "they give 1.027; lower the volume or raise the area"]),
    ("set-curve-area-length-beyond-the-isoperimetric-inequality",
     lambda d: ["circle", "--set", "volume=8", "--set", "area=9"],
     ["volume = 8 and area = 9 (a curve's enclosed area and length) are impossible targets: the isoperimetric "
      "inequality 4 pi A <= L^2 (equal only for a circle, which no polygon is) bounds 4 pi A / L^2 by 1, and they "
      "give 1.241"]),
]


@pytest.mark.parametrize(("make", "expect"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                  make: Callable[[Path], list[str]], expect: list[str]) -> None:
    argv = make(tmp_path)
    out = tmp_path / "run"
    before = sorted(p.name for p in tmp_path.iterdir())
    rc = cli.main(["run", *argv, "--out", str(out), "--steps", "2", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("willmore-nlp: error: ")
    for frag in expect:
        assert frag in lines[0], f"{frag!r} not in {lines[0]!r}"
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_enough_cases() -> None:
    kinds = {name.split("-")[0] for name, _, _ in CASES}
    assert len(CASES) >= 20 and {"curve", "npz", "obj", "off", "toml", "set"} <= kinds


def test_lenient_inputs_are_read(tmp_path: Path) -> None:
    """A Latin-1 byte in an OBJ comment and a UTF-8 BOM in a TOML config are accepted."""
    from willmore_nlp.config import resolve
    from willmore_nlp.mesh.io import load_mesh

    (tmp_path / "s.obj").write_bytes(_ico_obj().encode() + b"# modelled by Ren\xe9\n")
    assert load_mesh(tmp_path / "s.obj").n_simplices == 20
    (tmp_path / "c.txt").write_text(_circle_txt(12))
    (tmp_path / "cfg.toml").write_bytes(b'\xef\xbb\xbfmesh = "c.txt"\nsteps = 3\n')
    assert resolve(str(tmp_path / "cfg.toml")).steps == 3
    # a byte-order mark in OBJ, OFF and curve files (Windows editors write one; it was "unknown OBJ statement")
    (tmp_path / "b.obj").write_bytes(b"\xef\xbb\xbf# exported\n" + _ico_obj().encode())
    (tmp_path / "b.off").write_bytes(b"\xef\xbb\xbfOFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    (tmp_path / "b.txt").write_bytes(b"\xef\xbb\xbf" + _circle_txt(12).encode())
    assert [load_mesh(tmp_path / f).n_simplices for f in ("b.obj", "b.off", "b.txt")] == [20, 1, 12]
    # an STL 3e-8 wide: its corners are joined where exactly equal (trimesh's merge rounded to 1e-8: "simplex 0
    # repeats a vertex")
    import trimesh

    ico = shapes.icosphere(1)
    trimesh.Trimesh(1.5e-8 * ico.vertices, ico.simplices, process=False).export(tmp_path / "tiny.stl")
    tiny = load_mesh(tmp_path / "tiny.stl")
    assert (tiny.n_vertices, tiny.n_simplices) == (ico.n_vertices, ico.n_simplices)


def test_negative_steps_name_the_option(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert cli.main(["run", "circle", "--out", str(tmp_path / "r"), "--steps", "-3"]) == 2
    assert capsys.readouterr().err.strip() == ("willmore-nlp: error: --steps must be an integer >= 1 (the total "
                                               "number of steps), got -3")


def test_existing_output_and_resume_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert cli.main(["run", "circle", "--set", "n=12", "--out", str(out), "--steps", "1", "--quiet"]) == 2
    assert "output directory exists and is not empty" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    assert cli.main(["run", "--resume", str(out), "--quiet"]) == 2
    assert "not a run directory (missing config.json)" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    assert cli.main(["run", "--resume", str(out), "circle", "--quiet"]) == 2
    assert "give no TARGET" in capsys.readouterr().err
    assert cli.main(["run", "--quiet"]) == 2
    assert "needs a TARGET" in capsys.readouterr().err


def test_subprocess_no_traceback_unless_debug(tmp_path: Path) -> None:
    (tmp_path / "s.obj").write_text(OBJ_BAD_INDEX)
    args = ["run", str(tmp_path / "s.obj"), "--out", str(tmp_path / "run"), "--steps", "1"]
    r = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    assert r.stderr.strip() == f"willmore-nlp: error: {tmp_path / 's.obj'}:4: face index 9 is out of range " \
                               f"(the file has 3 vertices)"
    r = subprocess.run([*CLI, "--debug", *args], capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "Traceback" in r.stderr and "MeshError" in r.stderr
    assert not (tmp_path / "run").exists()


def test_tau_tilde_far_above_h2_warns(tmp_path: Path) -> None:
    mesh = shapes.regular_polygon(16)
    with pytest.warns(StepSizeWarning, match=r"h\^2 .*docs/theory/tau_tilde.md"):
        WillmoreFlow(mesh, mesh.h, 10 * mesh.h**2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", StepSizeWarning)
        WillmoreFlow(mesh, mesh.h, mesh.h**2)  # the problems' default tau_tilde = h^2: no warning
    save_mesh(mesh, tmp_path / "c.txt")
    r = subprocess.run([*CLI, "run", str(tmp_path / "c.txt"), "--out", str(tmp_path / "run"), "--steps", "1",
                        "--set", f"tau_tilde={10 * mesh.h**2}", "--quiet"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    warn = [ln for ln in r.stderr.splitlines() if "warning" in ln]
    assert len(warn) == 1 and warn[0].startswith("willmore-nlp: warning: tau_tilde = ") and "10 h^2" in warn[0]


def test_tau_tilde_far_below_h2_warns_where_ipopt_takes_the_steps() -> None:
    """A new user's tau_tilde = 1e-8 (1e-7 h^2 on a 162-vertex ellipsoid) failed every attempt with an IPOPT message
    that did not name it; below TAU_TILDE_LOW_FACTOR h^2 the flow now says so, when IPOPT is its solver."""
    mesh = shapes.icosphere(2)
    with pytest.warns(StepSizeWarning, match=r"tau_tilde = .* is 1e-06 h\^2 .*below about 0.0001 h\^2 IPOPT"):
        WillmoreFlow(mesh, mesh.h, 1e-6 * mesh.h**2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", StepSizeWarning)
        WillmoreFlow(mesh, mesh.h, mesh.h**2 / 100)  # the default
        WillmoreFlow(mesh, mesh.h, mesh.h**2 / 1e4)  # (at the threshold; one ulp below 1e-4 h^2 it said "1e-4 h^2 is
        # below about 1e-4 h^2": a new user's check)
        WillmoreFlow(mesh, mesh.h, 1e-6 * mesh.h**2, solver="newton-krylov")  # (measured: it takes such steps)


def test_tau_tilde_far_below_h2_fails_ipopt_not_newton_krylov() -> None:
    """What TAU_TILDE_LOW_FACTOR's warning says, measured on a 162-vertex ellipsoid 1.5 : 1 : 0.8 (one step at tau =
    h, no retry, a move of 1.0 h): at 1e-4 h^2 IPOPT and newton-krylov take the step to the same X; at 1e-6 h^2 IPOPT
    fails it (about 10 s at its iteration limit) and newton-krylov, whose stopping test is relative, still takes it,
    to an X that differs from the 1e-4 h^2 step's by the O(tau_tilde) change only."""
    from willmore_nlp.flow import FlowError

    mesh = shapes.icosphere(2)
    mesh = mesh.with_vertices(mesh.vertices * [1.5, 1.0, 0.8])
    h = mesh.h

    def step(ratio: float, solver: str) -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", StepSizeWarning)
            flow = WillmoreFlow(mesh, h, ratio * h * h, solver=solver, max_retries=0)
        return flow.run(steps=1)[0].vertices

    X4 = step(1e-4, "ipopt")
    assert np.abs(X4 - step(1e-4, "newton-krylov")).max() < 1e-5 * h  # (measured 1.5e-6 h, in a move of 1.0 h)
    assert np.abs(step(1e-6, "newton-krylov") - X4).max() < 1e-3 * h  # (the O(tau_tilde) change: measured 1.6e-4 h)
    with pytest.raises(FlowError, match="step 1 at t=0 failed"):
        step(1e-6, "ipopt")


def test_resume_of_a_file_outside_a_run_directory(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Found by a new-user check (2026-12-01): ``run --resume in/ok.txt`` (a mesh file) said "(the run directory is
    in)"; only a file inside a run directory (its config.json) names that directory."""
    (tmp_path / "in").mkdir()
    mesh = tmp_path / "in" / "ok.txt"
    mesh.write_text(_circle_txt(12))
    assert cli.main(["run", "--resume", str(mesh), "--quiet"]) == 2
    assert capsys.readouterr().err.strip() == f"willmore-nlp: error: {mesh}: a file, not a run directory"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_several_components_allowed_on_request(tmp_path: Path) -> None:
    _two_circles(tmp_path)
    out = tmp_path / "run"
    rc = cli.main(["run", str(tmp_path / "two.npz"), "--set", "allow_components=true", "--out", str(out),
                   "--steps", "1", "--quiet"])
    assert rc == 0 and (out / "states" / "state_000001.npz").is_file()


def test_output_paths_that_cannot_be_made_and_compare_misuse(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Found by a new-user check (2026-11-30): a file where the run directory's parent must go, a name too long and a
    symlink loop printed Python tracebacks (exit 1); ``compare`` wrote its study into a run directory (whose report
    then became the study's), hung with ``--workers 0`` and accepted ``--steps 0`` and ``--t-end -1``. Each is now
    one line and exit 2, and nothing is written. Another (2026-12-03): a dangling symbolic link read "File exists", a
    file where a folder must go "Not a directory", and a folder that takes no new folder or file (/proc) was an
    internal error; the message now names the part of the path in the way."""
    (tmp_path / "afile").write_text("x")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere" / "dir")
    run = tmp_path / "run"
    assert cli.main(["run", "circle", "--set", "n=12", "--out", str(run), "--steps", "1", "--quiet"]) == 0
    capsys.readouterr()
    before = sorted(p.name for p in tmp_path.iterdir())
    listing = sorted(p.name for p in run.iterdir())
    cases = [
        (["run", "circle", "--out", str(tmp_path / "afile" / "sub"), "--steps", "1"],
         f"{tmp_path / 'afile'} is a file, where a folder must go"),
        (["report", str(run), "--out", str(tmp_path / "afile" / "r")], "afile is a file, where a folder must go"),
        (["run", "circle", "--out", str(tmp_path / "dangling" / "r"), "--steps", "1"],  # (it said "File exists")
         f"dangling is a symbolic link to {tmp_path / 'nowhere' / 'dir'}, which does not exist"),
        (["export", str(run), "--out", str(tmp_path / "dangling")], "dangling is a symbolic link to"),
        (["run", "circle", "--out", str(tmp_path / ("a" * 300)), "--steps", "1"], "File name too long"),
        (["run", "circle", "--out", str(tmp_path / "loop" / "x"), "--steps", "1"], "Too many levels of symbolic links"),
        (["export", str(run), "--out", str(tmp_path / "afile")], "afile is a file, where a folder must go"),
        (["run", "--resume", str(run / "config.json"), "--steps", "2"],
         f"{run / 'config.json'}: a file, not a run directory (the run directory is {run})"),
        (["run", "circle", "--out", str(tmp_path / "r2"), "--t-end", "inf"], "--t-end must be a finite number > 0"),
        (["compare", "circle", "--out", str(run), "--steps", "1", "--workers", "1"],
         f"--out {run}: is a run directory, not a study directory"),
        (["compare", "circle", "--out", str(tmp_path / "s"), "--steps", "1", "--workers", "0"],
         "--workers must be an integer >= 1, got 0"),
        (["compare", "circle", "--out", str(tmp_path / "s"), "--steps", "0"], "--steps must be an integer >= 1"),
        (["compare", "circle", "--out", str(tmp_path / "s"), "--t-end", "-1"], "--t-end must be a finite number > 0"),
        (["run", "circle", "--out", str(tmp_path / "r3"), "--set", "steps=0", "--steps", "3"],
         "steps is given twice, by --set steps=0 and by --steps 3: give one"),  # (it ran 3 steps silently)
        (["run", "circle", "--out", str(tmp_path / "r3"), "--set", "t_end=0.5", "--t-end", "0.1"],
         "t_end is given twice, by --set t_end=0.5 and by --t-end 0.1"),
        (["compare", "circle", "--out", str(tmp_path / "s"), "--set", "t_end=0.5", "--t-end", "0.1"],
         "t_end is given twice"),
    ]
    if Path("/proc/self").is_dir():  # Linux: folders that take no new folder or file were internal errors (exit 70)
        cases += [(["run", "circle", "--out", "/proc/willmore-run", "--steps", "1"],
                   "/proc/willmore-run: cannot make this folder"),
                  (["export", str(run), "--out", "/proc/willmore.txt"],
                   "/proc/willmore.txt: cannot make a file in /proc")]
    for argv, text in cases:
        assert cli.main(argv) == 2, argv
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("willmore-nlp: error: ") and text in lines[0], (argv, lines)
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert sorted(p.name for p in run.iterdir()) == listing

