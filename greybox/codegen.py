"""Compile CasADi functions to C once and cache the shared library on disk.

The fitter's per-interval function is evaluated many times; generated C runs it several
times faster than CasADi's virtual machine. Compilation takes a few seconds, so the
library is cached under ``$GREYBOX_CACHE`` (default ``~/.cache/greybox``), keyed by a hash
of the function's serialised form: a second fit of the same model structure loads it at
once. Without a C compiler (or with ``GREYBOX_NO_COMPILE=1``) the function is used as is.

The cache key is the function itself (a hash of its serialised form, the C compiler's
optimisation flag and CasADi's version): two flights of one vehicle, or two processes,
that build the same function share one library, and a function that differs in anything
(an effect's option, an edited user effect, another airframe constant) gets its own.
"""
from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import signal
import subprocess
import tempfile
import warnings
import weakref
from pathlib import Path

import casadi as ca
import numpy as np

from .errors import CacheWarning

__all__ = ["compiled", "cached", "code_size", "expected_build_seconds", "add_vm_seconds", "library_path", "precompile", "cache_dir", "compiler_available",
           "Build", "start_build", "running_build", "queue_builds", "poll_builds", "cancel_builds",
           "finish_builds_at_exit", "discard_broken", "CacheWarning"]

# Seconds of C compiler time per instruction (:func:`code_size`; gcc 12, one core, the
# step functions of a Crazyflie's models, 8k-20k instructions: -O1 1.0-2.2 s, -O0 about a third)
BUILD_SECONDS_PER_INSTRUCTION = {"-O0": 3.5e-5, "-O1": 1e-4}


def cache_dir() -> Path:
    return Path(os.environ.get("GREYBOX_CACHE", Path.home() / ".cache" / "greybox"))


def compiler_available() -> str | None:
    """Path of the C compiler used (``$CC`` or gcc/cc), or None."""
    if os.environ.get("GREYBOX_NO_COMPILE"):
        return None
    return shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")


def code_size(f: ca.Function) -> int:
    """Instructions of ``f`` and, once each, of every function it calls (through its MX graph
    or a conditional's branches, at any depth): what the C compiler works through (an MX
    function's own count is that of its nodes only)."""
    # keyed by name and size: two functions of one name (a wrapper and what it wraps) once
    # counted as one, the wrapper's 34 instructions for its callee's 2132
    seen: dict[tuple[str, int], ca.Function] = {}

    def visit(g: ca.Function) -> None:
        key = (g.name(), g.n_instructions() if g.is_a("MXFunction") or g.is_a("SXFunction") else -1)
        if key in seen:
            return
        seen[key] = g
        if g.is_a("MXFunction"):
            for k in range(g.n_instructions()):
                node = g.instruction_MX(k)
                if node.is_call():
                    visit(node.which_function())
        elif not g.is_a("SXFunction"):
            for h in g.find_functions(1):      # a conditional (Switch): its branches
                visit(h)

    visit(f)
    return sum(g.n_instructions() for g in seen.values() if g.is_a("MXFunction") or g.is_a("SXFunction"))


def expected_build_seconds(f: ca.Function, opt: str = "-O1") -> float:
    """About how long the C compiler takes on ``f`` (generation, compiling, linking)."""
    return BUILD_SECONDS_PER_INSTRUCTION.get(opt, BUILD_SECONDS_PER_INSTRUCTION["-O1"]) * code_size(f)


# Seconds each function (by its library path) has run on CasADi's virtual machine, summed
# over every problem that used it, in this process and in earlier runs (a ``.vmtime`` file
# beside the library, appended in steps of VM_TIME_STEP): many short fits of one model
# structure, or the same short job run again, add up to a compile as one long fit does.
_vm_seconds: dict[Path, float] = {}
_vm_unsaved: dict[Path, float] = {}
VM_TIME_STEP = 0.25


def _vm_file(lib: Path) -> Path:
    return lib.with_suffix(".vmtime")


def _saved_vm_seconds(lib: Path) -> float:
    try:
        return float(sum(float(x) for x in _vm_file(lib).read_text().split()))
    except (OSError, ValueError):
        return 0.0          # none yet, or unreadable: start from zero


def add_vm_seconds(lib: Path, seconds: float) -> float:
    """Add ``seconds`` of virtual-machine evaluation of the function cached at ``lib``
    (:func:`library_path`); the total over this process and earlier runs."""
    if lib not in _vm_seconds:
        _vm_seconds[lib] = _saved_vm_seconds(lib)
    _vm_seconds[lib] += seconds
    _vm_unsaved[lib] = _vm_unsaved.get(lib, 0.0) + seconds
    if _vm_unsaved[lib] >= VM_TIME_STEP:
        try:
            # one short append per step: concurrent runs add their lines, none is lost
            lib.parent.mkdir(parents=True, exist_ok=True)
            with open(_vm_file(lib), "a") as fh:
                fh.write(f"{_vm_unsaved[lib]:.4f}\n")
            _vm_unsaved[lib] = 0.0
        except OSError:
            pass            # an unwritable cache: this process still counts
    return _vm_seconds[lib]


def library_path(f: ca.Function, opt: str = "-O1", key: str | None = None) -> Path:
    """Where the compile cache keeps ``f``'s library (whether or not it is there yet)."""
    return _lib_path(f, key, opt)


_names: "weakref.WeakKeyDictionary[ca.Function, dict[str, str]]" = weakref.WeakKeyDictionary()
"""Per function (held weakly) its library's file name by optimisation level: serialising a
large function to hash it takes tens of ms, and a diagnosis asks for the same ones often."""


def _lib_path(f: ca.Function, key: str | None, opt: str) -> Path:
    # the serialised function (20 ms for 36k instructions) is the exact key; an explicit
    # ``key`` is the caller's promise that it determines ``f``
    if key is not None:
        return cache_dir() / _file_name(f, key, opt)
    names = _names.setdefault(f, {})
    if opt not in names:
        names[opt] = _file_name(f, f.serialize(), opt)
    return cache_dir() / names[opt]


def _file_name(f: ca.Function, text: str, opt: str) -> str:
    digest = hashlib.sha1((text + opt + ca.__version__).encode()).hexdigest()[:20]
    return f"{f.name()}_{digest}.so"


def _generate(f: ca.Function, folder: str) -> Path:
    # generate() writes into the given folder (with a trailing separator), no chdir needed
    src = Path(folder) / f"{f.name()}.c"
    cg = ca.CodeGenerator(src.name, {"with_header": False})
    cg.add(f)
    cg.generate(str(folder) + os.sep)
    return src


_warned: set[str] = set()


def _note(text: str) -> None:
    """Warn once per process (the CLI prints it as one ``greybox: warning:`` line)."""
    if text not in _warned:
        _warned.add(text)
        warnings.warn(text, CacheWarning, stacklevel=3)


def _compile_command(cc: str, opt: str, src: Path, out: Path) -> list[str]:
    return [cc, opt, "-fPIC", "-shared", str(src), "-o", str(out), "-lm"]


def _start_compiler(cmd: list[str], folder: Path) -> subprocess.Popen:
    # its own process group, so that an interrupt can end the driver *and* its cc1/as/ld;
    # its temporary files in our folder, which is removed whatever happens
    env = dict(os.environ, TMPDIR=str(folder))
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, env=env)


def _kill(proc: subprocess.Popen) -> None:
    """End a compiler's whole process group: SIGTERM (gcc removes its files), then SIGKILL."""
    for sig, wait in ((signal.SIGTERM, 2.0), (signal.SIGKILL, None)):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            break
        try:
            proc.wait(timeout=wait)
            break
        except subprocess.TimeoutExpired:
            continue
    proc.wait()


def _writable_cache() -> bool:
    try:
        cache_dir().mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".probe-", dir=cache_dir())
        os.close(fd)
        os.unlink(probe)
        return True
    except OSError as e:
        _note(f"compile cache {cache_dir()} is not writable ({e.strerror or e}); using CasADi's "
              "virtual machine (several times slower). Set GREYBOX_CACHE to a writable folder.")
        return False


def precompile(functions: "list[ca.Function]", workers: int = 2, opt: str = "-O1") -> None:
    """Compile several functions into the cache at once, ``workers`` compilers in parallel
    (code generation is serial; the C compiler runs concurrently), for a job known to need
    them all (the diagnosis' cold refits of every candidate). An interrupt kills every
    compiler started (their whole process groups) before it propagates."""
    cc = compiler_available()
    if cc is None:
        return
    todo = [(f, _lib_path(f, None, opt)) for f in functions]
    todo = [(f, lib) for f, lib in todo if not lib.exists()]
    if not todo or not _writable_cache():
        return
    running: list[Build] = []
    try:
        for f, lib in todo:
            while len(running) >= workers:
                running.pop(0).wait_and_install()
            running.append(Build(f, lib, cc, opt))
        while running:
            running.pop(0).wait_and_install()
    except BaseException:
        for build in running:
            build.cancel()
        raise


def _install(out: Path, lib: Path) -> None:
    # copy then rename: concurrent runs never load a half-written library
    tmp_lib = lib.with_suffix(f".{os.getpid()}.tmp")
    try:
        shutil.copyfile(out, tmp_lib)
        os.replace(tmp_lib, lib)
    except OSError:
        try:
            tmp_lib.unlink()
        except OSError:
            pass


def _build(f: ca.Function, lib: Path, cc: str, opt: str) -> bool:
    """Compile ``f`` into ``lib``; False if the compiler fails. Interrupts kill the compiler."""
    return Build(f, lib, cc, opt).wait_and_install(timeout=600) and lib.exists()


class Build:
    """A library being compiled in the background (:func:`start_build`): the caller goes on
    (on CasADi's virtual machine) and asks :meth:`result` now and then. The compiler runs in
    its own process group and temporary folder; :func:`cancel_builds` ends every one still
    running (the CLI does so before it exits after an interrupt; at a normal exit, too)."""

    def __init__(self, f: ca.Function, lib: Path, cc: str, opt: str):
        self.f, self.lib = f, lib
        self._replaces = lib.exists()     # a broken file under the name: load the new one privately
        # a plain folder, not a TemporaryDirectory: Python's exit-time clean-up of those runs
        # before our atexit handler and would delete a finished library before it is installed
        self._tmp = tempfile.mkdtemp(prefix="greybox-build-")
        try:
            src = _generate(f, self._tmp)
            self._out = Path(self._tmp) / "lib.so"
            self._proc: subprocess.Popen | None = _start_compiler(
                _compile_command(cc, opt, src, self._out), Path(self._tmp))
        except BaseException:
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        self._result: tuple[ca.Function, str] | None = None

    def done(self) -> bool:
        """Whether the compiler has finished (successfully or not)."""
        return self._proc is None or self._proc.poll() is not None

    def result(self) -> tuple[ca.Function, str] | None:
        """None while the compiler runs; then ``(function, how)`` as :func:`compiled` gives
        (``how`` = ``"compiled"``, or ``"virtual machine"`` with ``f`` when the compiler or
        the library failed, said once)."""
        if self._result is None and self.done():
            self._result = (self.f, "virtual machine")     # stays so if interrupted below
            self._result = self._finish()
        return self._result

    def wait_and_install(self, timeout: float | None = None) -> bool:
        """Wait for the compiler, then :meth:`install`; an interrupt, SIGTERM or the timeout
        ends the compiler and removes its files before it propagates."""
        try:
            if self._proc is not None:
                self._proc.wait(timeout=timeout)
        except BaseException:      # no orphaned cc1 left behind
            self.cancel()
            raise
        return self.install()

    def install(self) -> bool:
        """Put a finished library into the cache (no loading, no warning); whether it did."""
        proc, self._proc = self._proc, None
        self._forget()
        try:
            ok = proc is not None and proc.returncode == 0 and self._out.exists()
            if ok:
                _install(self._out, self.lib)
            return ok
        finally:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def _finish(self) -> tuple[ca.Function, str]:
        if self._proc is None:
            return self.f, "virtual machine"          # cancelled
        built = self.install()
        g = _load_checked(self.f, self.lib, private=self._replaces) if built and self.lib.exists() else None
        if g is None and self.lib.parent != cache_dir():
            return self.f, "virtual machine"    # the cache it was for has gone (GREYBOX_CACHE changed)
        if g is None:
            _note("the C compiler failed on a generated function; using CasADi's virtual machine"
                  if not built else f"compile cache: the library built for {self.f.name()} could not be "
                  "installed or does not reproduce it; using CasADi's virtual machine")
            return self.f, "virtual machine"
        return g, "compiled"

    def _forget(self) -> None:
        if _builds.get(self.lib) is self:
            del _builds[self.lib]

    def cancel(self) -> None:
        """End the compiler (its whole process group) and remove its files."""
        proc, self._proc = self._proc, None
        self._forget()
        if proc is not None and proc.poll() is None:
            _kill(proc)
        shutil.rmtree(self._tmp, ignore_errors=True)
        if self._result is None:
            self._result = (self.f, "virtual machine")


def _new_build(f: ca.Function, lib: Path, cc: str, opt: str) -> Build | None:
    """A started :class:`Build`, or None (said once) when code generation or starting the
    compiler fails: background work never breaks the fit that is running."""
    try:
        return Build(f, lib, cc, opt)
    except Exception as e:       # noqa: BLE001 - any failure means: stay on the virtual machine
        _note(f"could not start the C compiler on a generated function ({e}); using CasADi's "
              "virtual machine")
        return None


_builds: dict[Path, Build] = {}
_queued: dict[Path, tuple[ca.Function, str]] = {}
QUEUE_WORKERS = 1
"""Queued background builds (:func:`queue_builds`) run at most this many at a time (the fit
keeps the other core); a build a running fit needs now (:func:`start_build`) is started
beside them."""


def start_build(f: ca.Function, opt: str = "-O1", lib: Path | None = None) -> Build | None:
    """Start compiling ``f`` into the cache in the background and return at once; the build
    already running for the same library if there is one (a queued one is started now).
    None when there is no compiler or the cache cannot be written (the function then stays
    on the virtual machine)."""
    cc = compiler_available()
    if cc is None:
        return None
    lib = lib if lib is not None else _lib_path(f, None, opt)
    _queued.pop(lib, None)
    poll_builds()
    if lib in _builds:
        return _builds[lib]
    if not _writable_cache():
        return None
    build = _new_build(f, lib, cc, opt)
    if build is not None:
        _builds[lib] = build
    return build


def running_build(lib: Path) -> Build | None:
    """The background build of library ``lib`` if one is running."""
    return _builds.get(lib)


def queue_builds(functions: "list[ca.Function]", opt: str = "-O1") -> None:
    """Compile ``functions`` into the cache in the background, :data:`QUEUE_WORKERS` at a time,
    for work known to come (the next round's candidate refits): started and collected
    whenever :func:`poll_builds` runs (every evaluation of a fit in ``"auto"`` mode), so the
    fits meanwhile go on and find the libraries ready. Those cached or building are skipped."""
    if compiler_available() is None:
        return
    for f in functions:
        lib = _lib_path(f, None, opt)
        if lib not in _builds and lib not in _queued and not lib.exists():
            _queued[lib] = (f, opt)
    poll_builds()


def poll_builds() -> None:
    """Collect finished background builds (into the cache) and start queued ones."""
    for b in list(_builds.values()):
        if b.done():
            b.result()
    cc = compiler_available()
    while _queued and len(_builds) < QUEUE_WORKERS and cc is not None:
        lib, (f, opt) = next(iter(_queued.items()))
        del _queued[lib]
        if lib.parent != cache_dir() or lib.exists() or not _writable_cache():
            continue    # queued for another cache (GREYBOX_CACHE changed), or there already
        build = _new_build(f, lib, cc, opt)
        if build is not None:
            _builds[lib] = build


def cancel_builds() -> None:
    """End every background build still running (:class:`Build`) and forget the queued ones."""
    _queued.clear()
    for b in list(_builds.values()):
        b.cancel()


def finish_builds_at_exit() -> None:
    """Install the background builds that have finished (nothing loaded, nothing said) and
    end the rest: at interpreter exit, and by the CLI before it leaves after an interrupt."""
    _queued.clear()
    for b in list(_builds.values()):
        try:
            if b.done():
                b.install()
        finally:
            b.cancel()


atexit.register(finish_builds_at_exit)


def _elf_complete(path: Path) -> bool:
    """Whether ``path`` is a whole ELF shared library: every segment to be mapped and the
    section header table lie inside the file. A truncated file would pass ``dlopen`` and
    kill the process with SIGBUS on first use; garbage fails here too."""
    import struct
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
            size = os.fstat(fh.fileno()).st_size
            if len(head) < 52 or head[:4] != b"\x7fELF" or head[4] not in (1, 2) or head[5] not in (1, 2):
                return False
            is64, end = head[4] == 2, "<" if head[5] == 1 else ">"
            if is64:
                if len(head) < 64:
                    return False
                phoff, shoff = struct.unpack_from(end + "QQ", head, 32)
                phentsize, phnum, shentsize, shnum = struct.unpack_from(end + "HHHH", head, 54)
            else:
                phoff, shoff = struct.unpack_from(end + "II", head, 28)
                phentsize, phnum, shentsize, shnum = struct.unpack_from(end + "HHHH", head, 42)
            if shoff + shnum * shentsize > size or phoff + phnum * phentsize > size:
                return False
            fh.seek(phoff)
            table = fh.read(phnum * phentsize)
            for k in range(phnum):
                entry = table[k * phentsize:(k + 1) * phentsize]
                if is64:
                    p_type, _, p_offset, _, _, p_filesz = struct.unpack_from(end + "IIQQQQ", entry)
                else:
                    p_type, p_offset, _, _, p_filesz = struct.unpack_from(end + "IIIII", entry)
                if p_type == 1 and p_offset + p_filesz > size:      # PT_LOAD beyond the end
                    return False
            return True
    except (OSError, struct.error):
        return False


def _load_checked(f: ca.Function, lib: Path, private: bool = False) -> ca.Function | None:
    """The library's function if it is ``f``'s twin (same signature, same values at a test
    point), else None: a corrupt or foreign file under a cache name is never used.

    ``private`` loads a copy under a new name: the dynamic loader returns a library already
    loaded under the same path, so a rebuilt file must not be loaded by its old name."""
    path = lib
    if not _elf_complete(lib):
        return None    # loading a truncated library would crash the process (SIGBUS)
    try:
        if private:
            path = lib.with_suffix(f".{os.getpid()}.{id(f)}.so")
            shutil.copyfile(lib, path)
        g = ca.external(f.name(), str(path))
    except (RuntimeError, OSError):
        return None
    finally:
        if private:
            try:
                path.unlink()     # the loaded mapping stays valid
            except OSError:
                pass
    if g.n_in() != f.n_in() or g.n_out() != f.n_out():
        return None
    for i in range(f.n_in()):
        if g.sparsity_in(i) != f.sparsity_in(i):
            return None
    for i in range(f.n_out()):
        if g.sparsity_out(i) != f.sparsity_out(i):
            return None
    rng = np.random.default_rng(0)
    # three test points: positive O(1), either sign, near zero (branches such as |v| < v0)
    for lo, hi in ((0.5, 1.5), (-1.5, 1.5), (-0.01, 0.01)):
        args = [ca.DM(f.sparsity_in(i), rng.uniform(lo, hi, f.sparsity_in(i).nnz())) for i in range(f.n_in())]
        try:
            want = f.call(args)
            got = g.call(args)
        except RuntimeError:
            return None
        for a, b in zip(want, got):
            a, b = np.asarray(a.nonzeros()), np.asarray(b.nonzeros())
            if not np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True):
                return None
    return g


def discard_broken(lib: Path) -> None:
    """Remove a file under a cache name that :func:`cached` refused (broken, or another
    function's), saying so once, so that it is rebuilt."""
    _note(f"compile cache: {lib.name} was broken or not this function's; rebuilt")
    try:
        lib.unlink()
    except OSError:
        pass


def cached(f: ca.Function, key: str | None = None, opt: str = "-O1", lib: Path | None = None
           ) -> ca.Function | None:
    """The compiled twin of ``f`` if the cache holds a good one, else None (nothing is built).
    ``lib``: its :func:`library_path`, when known."""
    if compiler_available() is None:
        return None
    poll_builds()
    lib = lib if lib is not None else _lib_path(f, key, opt)
    return _load_checked(f, lib) if lib.exists() else None


def compiled(f: ca.Function, key: str | None = None, opt: str = "-O1", lib: Path | None = None
             ) -> tuple[ca.Function, str]:
    """``(function, how)``: the compiled twin of ``f`` (``how`` = ``"cached"`` or ``"compiled"``)
    or ``f`` itself (``how`` = ``"virtual machine"``) when no compiler works.

    ``key``, when given, must determine ``f`` completely; without it (the usual way) the
    serialised function is hashed; ``lib``: its :func:`library_path`, when already known.
    A cached library is checked against ``f`` before use; a broken one is rebuilt. When the
    cache cannot be written, a warning says so once and ``f`` runs as is."""
    cc = compiler_available()
    if cc is None:
        return f, "virtual machine"
    lib = lib if lib is not None else _lib_path(f, key, opt)
    broken = False
    if lib.exists():
        g = _load_checked(f, lib)
        if g is not None:
            return g, "cached"
        broken = True
        _note(f"compile cache: {lib.name} was broken or not this function's; rebuilt")
        try:
            lib.unlink()
        except OSError:
            pass
    if not _writable_cache():
        return f, "virtual machine"
    if not _build(f, lib, cc, opt):
        _note("the C compiler failed on a generated function; using CasADi's virtual machine")
        return f, "virtual machine"
    g = _load_checked(f, lib, private=broken)
    if g is None:
        _note(f"compile cache: the library built for {f.name()} does not reproduce it; using "
              "CasADi's virtual machine")
        return f, "virtual machine"
    return g, "compiled"
