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
