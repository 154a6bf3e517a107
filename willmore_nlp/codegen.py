"""Generated C for the element kernels, compiled with the system compiler, cached by content hash.

Only the five element kernels of a step problem are generated (their C source does not depend on
the mesh: the assembly maps them over the elements), compiled into one shared library and loaded
with :func:`casadi.external`. The library is cached in a per-user directory under a key hashing
the generated source, the compiler (path and ``--version``), the flags, the CasADi version and the
platform. Each entry is a library plus a JSON manifest holding the key and the library's sha256;
an entry whose manifest or hash does not match is deleted and rebuilt, never loaded. Builds are
written to a temporary file and renamed into place under an exclusive lock, so concurrent
processes building the same key are safe.
"""

from __future__ import annotations

import atexit
import fcntl
import hashlib
import json
import logging
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from typing import Any

import casadi as ca

from willmore_nlp.errors import UserInputError
from willmore_nlp.model.step import KERNEL_NAMES

log = logging.getLogger(__name__)

DEFAULT_FLAGS: tuple[str, ...] = ("-O2",)
"""Optimisation flags (``-fPIC -shared`` are always added). Override with $WILLMORE_NLP_CFLAGS."""

MANIFEST_VERSION = 1


class CodegenError(UserInputError):
    """No compiler, or the compiler failed on generated code (its output is in the message)."""


def cache_dir() -> Path:
    """The cache directory: $WILLMORE_NLP_CACHE, else $XDG_CACHE_HOME/willmore_nlp, else ~/.cache/willmore_nlp."""
    env = os.environ.get("WILLMORE_NLP_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "willmore_nlp"


def find_compiler() -> str | None:
    """Path of the C compiler to use: $CC, else cc, gcc or clang on PATH (with a warning when $CC is set but not
    found); None if there is none."""
    env = os.environ.get("CC")
    for cand in (env, "cc", "gcc", "clang"):
        if cand:
            path = shutil.which(cand)
            if path:
                if env and cand != env:
                    _cc_not_found(env, path)
                return path
    return None


@cache
def _cc_not_found(env: str, path: str) -> None:
    """Warn (once per process) that $CC = ``env`` was not found and ``path`` compiles instead."""
    warnings.warn(f"$CC = {env!r} is not an executable on PATH: compiling with {path} instead", stacklevel=3)


@cache
def _compiler_id(cc: str) -> str:
    r = subprocess.run([cc, "--version"], capture_output=True, text=True, check=False)
    return f"{os.path.realpath(cc)}\n{r.stdout.strip()}"


def default_flags() -> tuple[str, ...]:
    """Flags from $WILLMORE_NLP_CFLAGS (space separated) or :data:`DEFAULT_FLAGS`."""
    env = os.environ.get("WILLMORE_NLP_CFLAGS")
    return tuple(env.split()) if env else DEFAULT_FLAGS


def generate_source(kernels: dict[str, ca.Function]) -> str:
    """C source of the kernels (one file, no header; size independent of the mesh).

    Besides the kernels, the reverse derivatives ``adj1_<name>`` of the value kernels k_f, k_g (and
    k_h) are generated: CasADi's external functions find them by name, which makes the compiled
    f and g differentiable (IPOPT's setup builds the gradient of the Lagrangian from them once).
    """
    cg = ca.CodeGenerator("willmore_kernels.c", {"with_header": False, "verbose": False})
    for k in KERNEL_NAMES:
        if k in kernels:
            cg.add(kernels[k])
    for k in ("k_f", "k_g", "k_h"):
        if k in kernels:
            cg.add(kernels[k].reverse(1))
    return cg.dump()


def cache_key(source: str, cc: str, flags: tuple[str, ...]) -> str:
    """sha256 over the generated source, compiler identity, flags, CasADi version and platform."""
    h = hashlib.sha256()
    for part in (
        source,
        _compiler_id(cc),
        " ".join(flags),
        ca.__version__,
        platform.platform(),
        platform.machine(),
        sys.implementation.cache_tag or "",
        str(MANIFEST_VERSION),
    ):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _valid_entry(lib: Path, manifest: Path, key: str) -> bool:
    """True when ``lib`` exists with a manifest naming ``key`` and the library's current hash."""
    if not (lib.is_file() and manifest.is_file()):
        return False
    try:
        meta = json.loads(manifest.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return (
        isinstance(meta, dict)
        and meta.get("key") == key
        and meta.get("version") == MANIFEST_VERSION
        and meta.get("sha256") == _sha256_file(lib)
    )


def _remove(*paths: Path) -> None:
    for p in paths:
        p.unlink(missing_ok=True)


def build_library(
    source: str,
    *,
    flags: tuple[str, ...] | None = None,
    directory: Path | None = None,
    name: str = "willmore_kernels",
) -> tuple[Path, dict[str, Any]]:
    """Compile ``source`` into a cached shared library (or reuse a valid cached one).

    Returns
    -------
    lib : path of the shared library
    info : ``{"key", "cached": bool, "compile_time": seconds, "source_bytes", "flags"}``

    Raises
    ------
    CodegenError
        No C compiler, or compilation failed.
    """
    cc = find_compiler()
    if cc is None:
        raise CodegenError("no C compiler found (set $CC or install gcc); use codegen=False")
    flags = default_flags() if flags is None else tuple(flags)
    key = cache_key(source, cc, flags)
    d = cache_dir() if directory is None else Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    lib = d / f"{name}_{key[:24]}.so"
    manifest = lib.with_suffix(".json")
    info: dict[str, Any] = {"key": key, "cached": True, "compile_time": 0.0, "source_bytes": len(source),
                            "flags": list(flags), "library": str(lib)}
    if _valid_entry(lib, manifest, key):
        return lib, info
    with _locked(d / f".{name}_{key[:24]}.lock"):
        if _valid_entry(lib, manifest, key):  # built by another process meanwhile
            return lib, info
        if lib.exists() or manifest.exists():
            log.warning("cache entry %s is corrupt or foreign: rebuilding", lib)
            _remove(lib, manifest)
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(dir=d, prefix=".build_") as tmp:
            (Path(tmp) / "pid").write_text(str(os.getpid()), encoding="utf-8")  # cache_clear: is it abandoned?
            c_file = Path(tmp) / f"{name}.c"
            c_file.write_text(source, encoding="utf-8")
            out = Path(tmp) / f"{name}.so"
            cmd = [cc, *flags, "-fPIC", "-shared", str(c_file), "-o", str(out), "-lm"]
            r = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if r.returncode != 0:
                lines = [ln.strip() for ln in r.stderr.splitlines() if ln.strip()]
                why = next((ln for ln in lines if "error" in ln.lower()), lines[-1] if lines else "no message")
                raise CodegenError(f"compiling the element kernels failed: '{cc} {' '.join(flags)}' exited with "
                                   f"{r.returncode} ({why}); check $CC and $WILLMORE_NLP_CFLAGS, or set "
                                   f"codegen=false (CasADi's virtual machine)")
            os.replace(out, lib)
        meta = {"key": key, "version": MANIFEST_VERSION, "sha256": _sha256_file(lib), "flags": list(flags),
                "compiler": _compiler_id(cc).splitlines()[0], "casadi": ca.__version__}
        tmp_manifest = manifest.with_suffix(".json.tmp")
        tmp_manifest.write_text(json.dumps(meta, indent=1), encoding="utf-8")
        os.replace(tmp_manifest, manifest)
        info.update(cached=False, compile_time=time.perf_counter() - t0)
    return lib, info


def compile_kernels(
    kernels: dict[str, ca.Function],
    *,
    flags: tuple[str, ...] | None = None,
    directory: Path | None = None,
    info: dict[str, Any] | None = None,
) -> dict[str, ca.Function]:
    """Compiled versions of the element kernels (same keys and signatures, as ``casadi.external``).

    Parameters
    ----------
    kernels : the five kernels of a :class:`~willmore_nlp.model.step.StepProblem`
    flags : compiler flags (default: :func:`default_flags`)
    directory : cache directory (default: :func:`cache_dir`)
    info : if given, filled with the build information (key, cached, compile time, ...)
    """
    source = generate_source(kernels)
    try:
        lib, meta = build_library(source, flags=flags, directory=directory)
    except OSError as exc:  # read-only or full cache directory: build in a temporary one this time
        where = cache_dir() if directory is None else Path(directory)
        tmp = Path(tempfile.mkdtemp(prefix="willmore_nlp_kernels_"))
        atexit.register(shutil.rmtree, tmp, True)
        warnings.warn(f"cannot write the kernel cache {where} ({exc.strerror or exc}): compiling into the temporary "
                      f"directory {tmp} this time (set $WILLMORE_NLP_CACHE to a writable directory)", stacklevel=2)
        lib, meta = build_library(source, flags=flags, directory=tmp)
    if info is not None:
        info.update(meta)
    return {k: ca.external(kernels[k].name(), str(lib)) for k in KERNEL_NAMES if k in kernels}


def cache_info(directory: Path | None = None) -> dict[str, Any]:
    """Entries, total size and location of the cache."""
    d = cache_dir() if directory is None else Path(directory)
    libs = sorted(d.glob("*.so")) if d.is_dir() else []
    return {
        "directory": str(d),
        "entries": len(libs),
        "bytes": sum(p.stat().st_size for p in libs),
        "libraries": [p.name for p in libs],
    }


def _abandoned_build(p: Path) -> bool:
    """True for a ``.build_*`` directory whose compiling process is gone (killed mid-compilation)."""
    try:
        pid = int((p / "pid").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return time.time() - p.stat().st_mtime > 3600  # no pid yet: only when clearly stale
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


def cache_clear(directory: Path | None = None) -> int:
    """Delete every cache entry and the build directories of killed compilations; returns how many
    libraries were removed."""
    d = cache_dir() if directory is None else Path(directory)
    if not d.is_dir():
        return 0
    n = 0
    for p in d.iterdir():
        if p.suffix == ".so":
            n += 1
        if p.is_file() and (p.suffix in (".so", ".json", ".tmp", ".lock")):
            p.unlink()
        elif p.is_dir() and p.name.startswith(".build_") and _abandoned_build(p):
            shutil.rmtree(p, ignore_errors=True)
    return n
