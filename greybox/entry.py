"""The ``greybox`` console script: signal handling first, then the (heavy) imports.

Ctrl-C or SIGTERM at any moment, also while numpy, scipy and CasADi are still being
imported, ends the run with one line and exit status 130 (143 for SIGTERM).
"""
from __future__ import annotations

import os
import signal
import sys
from typing import Sequence

from .errors import interrupt_status, raise_interrupted, raise_terminated

__all__ = ["run"]


def run(argv: Sequence[str] | None = None) -> int:
    """Install the signal handlers, import the CLI and run it (the process's entry point:
    after an interrupt it ends the process itself, see below)."""
    try:
        signal.signal(signal.SIGTERM, raise_terminated)
        # kill -INT interrupts also when a shell script started us in the background
        # (which it does with SIGINT ignored)
        signal.signal(signal.SIGINT, raise_interrupted)
    except ValueError:      # not the main thread
        return _run(argv)
    code = _run(argv)
    if code in (130, 143):
        # An interrupt that landed inside code an extension module ran through the C API
        # (e.g. while CasADi was being imported) marks it "unhandled" for the interpreter,
        # which would then kill itself with SIGINT at exit although we handled it: leave now,
        # with our status (every clean-up has run: the exception went through it).
        # os._exit runs no atexit handler: keep the background builds that have finished and
        # end the compilers still running (a second Ctrl-C meanwhile changes nothing)
        codegen = sys.modules.get("greybox.codegen")
        if codegen is not None:
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
                signal.signal(signal.SIGTERM, signal.SIG_IGN)
                codegen.finish_builds_at_exit()
            except BaseException:   # noqa: BLE001 - leaving with our status matters more
                pass
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def _run(argv: Sequence[str] | None) -> int:
    try:
        from .cli import main
        return main(argv)
    except BaseException as e:   # an interrupt while the CLI was being imported
        status = interrupt_status(e)
        if status is None:
            raise
        return status
