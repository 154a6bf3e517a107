"""Generated C kernels: same results as the virtual machine, content-hashed cache, robustness."""

import numpy as np
import pytest

from willmore_nlp import WillmoreFlow
from willmore_nlp import codegen as cgm
from willmore_nlp.mesh import shapes
from willmore_nlp.model.build import build_step

pytestmark = pytest.mark.skipif(cgm.find_compiler() is None, reason="no C compiler")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("WILLMORE_NLP_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


@pytest.mark.parametrize("make", [lambda: shapes.ellipse(40, 2.0, 1.0), lambda: shapes.icosphere(2)])
def test_codegen_on_off_same_step(cache, make) -> None:
    mesh = make()
    h = mesh.h
    runs = []
    for cg in (True, False):
        flow = WillmoreFlow(mesh, h, 0.01 * h * h, codegen=cg, tol=1e-10)
        runs.append([r.vertices for r in flow.run(steps=2)])
        assert flow.codegen_info["enabled"] is cg
    for a, b in zip(*runs, strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(a).max())


def test_cache_hit_and_rebuilds(cache) -> None:
    kern = build_step(shapes.icosphere(1)).problem.kernels
    info: dict = {}
    cgm.compile_kernels(kern, info=info)
    assert info["cached"] is False and info["compile_time"] > 0
    info2: dict = {}
    cgm.compile_kernels(kern, info=info2)
    assert info2["cached"] is True and info2["key"] == info["key"] and info2["compile_time"] == 0
    # other flags: other key, new build
    info3: dict = {}
    cgm.compile_kernels(kern, flags=("-O1",), info=info3)
    assert info3["cached"] is False and info3["key"] != info["key"]
    # another problem (curve kernels): other key
    info4: dict = {}
    cgm.compile_kernels(build_step(shapes.regular_polygon(8)).problem.kernels, info=info4)
    assert info4["cached"] is False and info4["key"] not in (info["key"], info3["key"])
    assert cgm.cache_info()["entries"] == 3
    assert cgm.cache_clear() == 3
    assert cgm.cache_info()["entries"] == 0


def test_truncated_or_foreign_library_is_rebuilt(cache) -> None:
    kern = build_step(shapes.regular_polygon(8)).problem.kernels
    info: dict = {}
    cgm.compile_kernels(kern, info=info)
    lib = cache / info["library"].split("/")[-1]
    data = lib.read_bytes()
    lib.write_bytes(data[: len(data) // 3])  # truncated by a crash
    info2: dict = {}
    fns = cgm.compile_kernels(kern, info=info2)
    assert info2["cached"] is False
    assert cgm._valid_entry(lib, lib.with_suffix(".json"), info["key"])
    xe = np.linspace(0.1, 1.0, fns["k_f"].size1_in(0))
    np.testing.assert_allclose(float(fns["k_f"](xe, [0.1, 0.01, 0.5])), float(kern["k_f"](xe, [0.1, 0.01, 0.5])))
    # a manifest from elsewhere (wrong key) is not trusted either
    man = lib.with_suffix(".json")
    man.write_text(man.read_text().replace(info["key"], "0" * 64))
    info3: dict = {}
    cgm.compile_kernels(kern, info=info3)
    assert info3["cached"] is False


def test_generated_source_independent_of_mesh_size() -> None:
    small = cgm.generate_source(build_step(shapes.icosphere(1)).problem.kernels)
    large = cgm.generate_source(build_step(shapes.icosphere(3)).problem.kernels)
    assert len(small) == len(large)
    assert small == large


def test_cli_cache_info_and_clear(cache) -> None:
    import os
    import subprocess
    import sys

    cgm.compile_kernels(build_step(shapes.regular_polygon(8)).problem.kernels)
    env = dict(os.environ, WILLMORE_NLP_CACHE=str(cache))
    cli = [sys.executable, "-m", "willmore_nlp.cli", "cache"]
    r = subprocess.run([*cli, "info"], capture_output=True, text=True, env=env, check=True)
    assert "entries: 1" in r.stdout and str(cache) in r.stdout
    r = subprocess.run([*cli, "clear"], capture_output=True, text=True, env=env, check=True)
    assert "removed 1" in r.stdout
    assert not list(cache.glob("*.so"))


def test_unwritable_cache_falls_back(tmp_path, monkeypatch) -> None:
    """A cache path that cannot be created (here below a regular file; read-only or full disks raise
    OSError the same way) compiles into a temporary directory; with no writable directory at all the
    kernels run in the virtual machine, with a warning naming codegen=false."""
    import tempfile

    (tmp_path / "file").write_text("not a directory")
    monkeypatch.setenv("WILLMORE_NLP_CACHE", str(tmp_path / "file" / "cache"))
    mesh = shapes.regular_polygon(8)
    with pytest.warns(UserWarning, match="cannot write the kernel cache .* temporary directory"):
        flow = WillmoreFlow(mesh, mesh.h, 0.25 * mesh.h**2, codegen=True)
    assert flow.codegen_info["enabled"] and str(tmp_path) not in flow.codegen_info["library"]
    X1 = flow.step().vertices
    monkeypatch.setattr(tempfile, "mkdtemp", lambda **kw: str(tmp_path / "file" / "tmp"))
    with pytest.warns(UserWarning) as caught:
        vm = WillmoreFlow(mesh, mesh.h, 0.25 * mesh.h**2, codegen=True)
    assert any("virtual machine" in str(w.message) and "codegen=false" in str(w.message) for w in caught)
    assert not vm.codegen_info["enabled"]
    np.testing.assert_allclose(vm.step().vertices, X1, rtol=0, atol=1e-12)


def test_cache_clear_removes_build_dirs_of_killed_compilations(cache) -> None:
    import os
    import subprocess

    cache.mkdir()
    p = subprocess.Popen(["true"])
    p.wait()
    killed = cache / ".build_abc123"
    killed.mkdir()
    (killed / "pid").write_text(str(p.pid))
    (killed / "willmore_kernels.c").write_text("int x;")
    live = cache / ".build_def456"
    live.mkdir()
    (live / "pid").write_text(str(os.getpid()))  # this process: a compilation under way
    cgm.cache_clear()
    assert not killed.exists() and live.exists()


def test_a_cc_that_is_not_found_says_which_compiler_is_used(monkeypatch) -> None:
    """$CC naming no executable was replaced by cc silently (found by a new-user check): now a warning, once."""
    import shutil
    import warnings

    if shutil.which("cc") is None:
        pytest.skip("no cc on PATH")
    monkeypatch.setenv("CC", "/nonexistent/cc")
    cgm._cc_not_found.cache_clear()
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        assert cgm.find_compiler() == cgm.find_compiler() == shutil.which("cc")
    assert [str(w.message) for w in seen] == [f"$CC = '/nonexistent/cc' is not an executable on PATH: compiling with "
                                              f"{shutil.which('cc')} instead"]
