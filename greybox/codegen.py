"""Compile CasADi functions to C once and cache the shared library on disk.

The fitter's per-interval function is evaluated many times; generated C runs it several
times faster than CasADi's virtual machine. Compilation takes a few seconds, so the
library is cached under ``$GREYBOX_CACHE`` (default ``~/.cache/greybox``), keyed by a hash
of the function's serialised form: a second fit of the same model structure loads it at
once. Without a C compiler (or with ``GREYBOX_NO_COMPILE=1``) the function is used as is.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca

__all__ = ["compiled", "precompile", "cache_dir", "compiler_available"]


def cache_dir() -> Path:
    return Path(os.environ.get("GREYBOX_CACHE", Path.home() / ".cache" / "greybox"))


def compiler_available() -> str | None:
    """Path of the C compiler used (``$CC`` or gcc/cc), or None."""
    if os.environ.get("GREYBOX_NO_COMPILE"):
        return None
    return shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")


def source_fingerprint() -> str:
    """Hash of the source that defines compiled functions: changing it invalidates cached libraries."""
    h = hashlib.sha1(ca.__version__.encode())
    # the modules that define what gets compiled (not the CLI, reports, ...)
    for name in ("airframe", "codegen", "effects", "fitting", "integrate", "model", "parameters"):
        h.update((Path(__file__).parent / f"{name}.py").read_bytes())
    return h.hexdigest()


def _lib_path(f: ca.Function, key: str | None, opt: str) -> Path:
    text = (key + source_fingerprint()) if key is not None else f.serialize()
    digest = hashlib.sha1((text + opt + ca.__version__).encode()).hexdigest()[:20]
    return cache_dir() / f"{f.name()}_{digest}.so"


def _generate(f: ca.Function, tmp: str) -> Path:
    src = Path(tmp) / f"{f.name()}.c"
    cg = ca.CodeGenerator(str(src.name), {"with_header": False})
    cg.add(f)
    cwd = os.getcwd()
    os.chdir(tmp)
    try:
        cg.generate()
    finally:
        os.chdir(cwd)
    return src


def precompile(items: "list[tuple[ca.Function, str | None]]", workers: int = 2, opt: str = "-O1") -> None:
    """Compile several functions into the cache at once, ``workers`` compilers in parallel
    (code generation is serial; the C compiler runs concurrently)."""
    cc = compiler_available()
    if cc is None:
        return
    todo = [(f, _lib_path(f, key, opt)) for f, key in items]
    todo = [(f, lib) for f, lib in todo if not lib.exists()]
    if not todo:
        return
    cache_dir().mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        jobs = []
        for i, (f, lib) in enumerate(todo):
            d = Path(tmp) / str(i)
            d.mkdir()
            jobs.append((_generate(f, str(d)), d / "lib.so", lib))
        running: list = []
        for src, out, lib in jobs:
            while len(running) >= workers:
                _finish(running.pop(0))
            running.append((subprocess.Popen([cc, opt, "-fPIC", "-shared", str(src), "-o", str(out), "-lm"],
                                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL), out, lib))
        for r in running:
            _finish(r)


def _finish(job) -> None:
    proc, out, lib = job
    if proc.wait() == 0 and out.exists():
        tmp_lib = lib.with_suffix(f".{os.getpid()}.tmp")
        shutil.copyfile(out, tmp_lib)
        os.replace(tmp_lib, lib)


def compiled(f: ca.Function, key: str | None = None, opt: str = "-O1") -> tuple[ca.Function, str]:
    """``(function, how)``: the compiled twin of ``f`` (``how`` = ``"cached"`` or ``"compiled"``)
    or ``f`` itself (``how`` = ``"virtual machine"``) when no compiler works.

    ``key`` must determine ``f`` completely (with greybox's source, which is added); without
    it the serialised function is hashed, which is exact but slower for large functions."""
    cc = compiler_available()
    if cc is None:
        return f, "virtual machine"
    lib = _lib_path(f, key, opt)
    how = "cached"
    if not lib.exists():
        how = "compiled"
        try:
            lib.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory() as tmp:
                src = _generate(f, tmp)
                out = Path(tmp) / "lib.so"
                subprocess.run([cc, opt, "-fPIC", "-shared", str(src), "-o", str(out), "-lm"],
                               check=True, capture_output=True, timeout=600)
                # rename is atomic: concurrent fits never load a half-written library
                tmp_lib = lib.with_suffix(f".{os.getpid()}.tmp")
                shutil.copyfile(out, tmp_lib)
                os.replace(tmp_lib, lib)
        except (OSError, subprocess.SubprocessError):
            return f, "virtual machine"
    try:
        return ca.external(f.name(), str(lib)), how
    except RuntimeError:
        return f, "virtual machine"
