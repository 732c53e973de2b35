"""A command run in the test's own interpreter, as its process would run it."""
from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from typing import Callable, Sequence


def in_process(main: Callable[[list[str]], int | None], argv: Sequence[str], cwd=None) -> subprocess.CompletedProcess:
    """``main(argv)`` of a command-line entry point in this interpreter: its exit code (a
    ``SystemExit``, argparse's usage errors included, as the interpreter maps it) and its two
    streams, as ``subprocess.run(..., capture_output=True, text=True)`` gets them from the command's
    process, without the half second of a new interpreter's imports. ``cwd``: the folder it runs in."""
    argv = [str(a) for a in argv]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), contextlib.chdir(cwd or os.getcwd()):
        try:
            code = main(argv)
        except SystemExit as stop:
            code = stop.code
            if not (code is None or isinstance(code, int)):  # SystemExit("message"): printed, status 1
                print(code, file=sys.stderr)
                code = 1
    return subprocess.CompletedProcess(argv, 0 if code is None else code, out.getvalue(), err.getvalue())
