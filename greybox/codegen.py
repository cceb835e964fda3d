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

__all__ = ["compiled", "cache_dir", "compiler_available"]


def cache_dir() -> Path:
    return Path(os.environ.get("GREYBOX_CACHE", Path.home() / ".cache" / "greybox"))


def compiler_available() -> str | None:
    """Path of the C compiler used (``$CC`` or gcc/cc), or None."""
    if os.environ.get("GREYBOX_NO_COMPILE"):
        return None
    return shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")


def source_fingerprint() -> str:
    """Hash of greybox's own source files: a change of the code invalidates cached libraries."""
    h = hashlib.sha1(ca.__version__.encode())
    for src in sorted(Path(__file__).parent.glob("*.py")):
        h.update(src.read_bytes())
    return h.hexdigest()


def compiled(f: ca.Function, key: str | None = None, opt: str = "-O1") -> tuple[ca.Function, str]:
    """``(function, how)``: the compiled twin of ``f`` (``how`` = ``"cached"`` or ``"compiled"``)
    or ``f`` itself (``how`` = ``"virtual machine"``) when no compiler works.

    ``key`` must determine ``f`` completely (with greybox's source, which is added); without
    it the serialised function is hashed, which is exact but slower for large functions."""
    cc = compiler_available()
    if cc is None:
        return f, "virtual machine"
    text = (key + source_fingerprint()) if key is not None else f.serialize()
    key = hashlib.sha1((text + opt + ca.__version__).encode()).hexdigest()[:20]
    lib = cache_dir() / f"{f.name()}_{key}.so"
    how = "cached"
    if not lib.exists():
        how = "compiled"
        try:
            lib.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory() as tmp:
                src = Path(tmp) / f"{f.name()}.c"
                cg = ca.CodeGenerator(str(src.name), {"with_header": False})
                cg.add(f)
                cwd = os.getcwd()
                os.chdir(tmp)
                try:
                    cg.generate()
                finally:
                    os.chdir(cwd)
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
