"""The planner's compiled numba kernels: where they are cached, and how they are compiled once
per machine.

* **One cache per machine.** Every ``cache=True`` kernel of the planner is cached under the
  user's cache folder (:func:`cache_root`: ``$NUMBA_CACHE_DIR`` when set, else
  ``$XDG_CACHE_HOME/marsupial-fleet/numba``, else ``~/.cache/marsupial-fleet/numba``), in a
  folder named by numba's version and the digest of the planner's sources (:func:`cache_dir`),
  whatever the checkout or environment the planner runs from: processes, virtual environments
  and copies of the same planner on one machine share one compilation.
* **Only today's sources.** A cached kernel is valid only for the planner sources it was
  compiled from (:func:`sources_digest`, all of them: numba itself checks a kernel against its
  own file only, so a rule inlined from another file, or a constant such as
  ``planner.ssap.TIE``, would otherwise stay as cached when that file changes). numba adds its
  own checks (its version, the Python version, the CPU).
* **One compiler per kernel per machine.** A process about to compile a kernel takes that
  kernel's lock file in the cache first; a process wanting the same kernel meanwhile waits for
  it and then loads what it saved. A fleet's processes starting together on a new machine
  compile each kernel once, not once per process.
* **Compilation says what it does.** :func:`report_compiles` gives a process's log the lines
  "compiling ..." / "compiled ... in N s" of every planner kernel it compiles (a kernel loaded
  from the cache says nothing), and "waiting for another process compiling ...".

Every kernel module calls :func:`cache_follows_sources` with its ``globals()`` at its end. Importing
this module does not import numba (a process sets :func:`report_compiles` before it knows whether
its planner has kernels). This relies on numba's cache classes (``numba.core.caching``; numba is pinned in constraints.txt, and
tests/test_numba_cache.py checks the mechanism).
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import sys
import time
from pathlib import Path
from typing import Callable

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no cross-process lock, each process compiles
    fcntl = None

#: The planner package's directory (whose sources :func:`sources_digest` hashes).
PACKAGE = Path(__file__).resolve().parent
#: The stamp's tag in a kernel's cache index (tests/test_numba_cache.py reads it).
STAMP_TAG = "planner-sources"


@functools.lru_cache(maxsize=1)
def sources_digest() -> str:
    """SHA-256 (hex) of every ``.py`` file of the planner package (relative path and content)."""
    h = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*.py")):
        h.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def cache_root() -> Path:
    """The folder of the machine's compiled planner kernels, all versions: ``$NUMBA_CACHE_DIR``
    when set, else the user's cache folder's ``marsupial-fleet/numba``."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    if sys.platform == "win32" and os.environ.get("LOCALAPPDATA"):  # pragma: no cover
        base = Path(os.environ["LOCALAPPDATA"])
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "marsupial-fleet" / "numba"


def cache_dir() -> Path:
    """The folder of today's planner kernels: :func:`cache_root` / ``numba-<version>-<digest>``
    (the digest's first 16 hex digits)."""
    import numba

    return cache_root() / f"numba-{numba.__version__}-{sources_digest()[:16]}"


@functools.lru_cache(maxsize=1)
def _cache_class():
    """The planner's numba cache class (numba imported on first use)."""
    from numba.core import event
    from numba.core.caching import CompileResultCacheImpl, FunctionCache, _CacheLocator

    class _CompileListener(event.Listener):
        """Reports the planner kernels numba compiles (its ``numba:compile`` event fires only when a
        kernel is not in the cache)."""

        def __init__(self):
            self._started = []  # start times of the compilations in progress (numba's compiler lock: one thread)

        def _name(self, ev):
            func = getattr(ev.data.get("dispatcher"), "py_func", None)
            module = getattr(func, "__module__", "") or ""
            return f"{module}.{func.__qualname__}" if module.startswith("planner.") else None

        def on_start(self, ev):
            name = self._name(ev)
            if name is None:
                return
            self._started.append(time.monotonic())
            if _reporter[0] is None:
                return
            if not _told_where[0]:
                _told_where[0] = True
                _report(f"compiling the planner's kernels, once for this machine (cache: {cache_dir()})")
            _report(f"compiling {name}")

        def on_end(self, ev):
            name = self._name(ev)
            if name is None or not self._started:
                return
            _report(f"compiled {name} in {time.monotonic() - self._started.pop():.1f} s")

    class _Locator(_CacheLocator):
        """A planner module's kernels in :func:`cache_dir`, under the module's path in the package;
        stamped with the sources digest instead of the file's time stamp."""

        def __init__(self, py_func, py_file):
            self._lineno = py_func.__code__.co_firstlineno
            module = Path(py_file).resolve().relative_to(PACKAGE.parent).with_suffix("")
            self._cache_path = str(cache_dir() / module)

        def get_cache_path(self):
            return self._cache_path

        def get_source_stamp(self):
            return (STAMP_TAG, sources_digest())

        def get_disambiguator(self):
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func, py_file):
            if not Path(py_file).resolve().is_relative_to(PACKAGE):
                return None
            try:
                self = cls(py_func, py_file)
                self.ensure_cache_path()
            except (OSError, RuntimeError):  # no home folder, or not writable: numba's own locators
                return None
            return self

    class _Impl(CompileResultCacheImpl):
        _locator_classes = [_Locator, *CompileResultCacheImpl._locator_classes]

    class _PlannerCache(FunctionCache):
        _impl_class = _Impl

    # Reports the planner kernels numba compiles: its numba:compile event fires only on a cache miss.
    event.register("numba:compile", _CompileListener())
    return _PlannerCache


def cache_follows_sources(namespace: dict) -> None:
    """Give every ``cache=True`` function defined in a module (``namespace`` is its
    ``globals()``; call at its end) the planner's cache: :func:`cache_dir`, valid only for
    today's sources, compiled by one process at a time (see the module's docstring)."""
    module = namespace["__name__"]
    for obj in list(namespace.values()):
        if getattr(getattr(obj, "_cache", None), "_cache_file", None) is None \
                or getattr(getattr(obj, "py_func", None), "__module__", None) != module:
            continue  # not a cached dispatcher, or one another module defines (and equips)
        obj._cache = _cache_class()(obj.py_func)
        stamp = obj._cache._cache_file._source_stamp
        if not (isinstance(stamp, tuple) and stamp[:1] == (STAMP_TAG,)):  # numba's own locator
            obj._cache._cache_file._source_stamp = (STAMP_TAG, sources_digest(), stamp)
        _one_compiler(obj)


# ------------------------------------------------------------------ one compiler per machine

_held: dict[str, list] = {}  # lock path -> [file, depth]: the locks this process holds


@contextlib.contextmanager
def _machine_lock(path: Path, name: str):
    """Hold the lock file ``path`` (reentrant within the process; call with numba's compiler
    lock held, so that one thread of a process at a time takes these)."""
    key = str(path)
    if fcntl is None:
        yield
        return
    if key in _held:
        _held[key][1] += 1
    else:
        try:
            handle = open(path, "a")
        except OSError:
            yield  # no lock file: compile unguarded
            return
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            start = time.monotonic()
            _report(f"waiting for another process compiling {name}")
            fcntl.flock(handle, fcntl.LOCK_EX)
            _report(f"waited {time.monotonic() - start:.1f} s for {name}")
        _held[key] = [handle, 1]
    try:
        yield
    finally:
        _held[key][1] -= 1
        if _held[key][1] == 0:
            handle = _held.pop(key)[0]
            fcntl.flock(handle, fcntl.LOCK_UN)
            handle.close()


def _one_compiler(dispatcher) -> None:
    """Make ``dispatcher`` compile a signature it has not loaded only under its kernel's lock
    file (the instance's ``compile`` shadows the class's: numba calls ``self.compile`` both for
    a call from Python and for a call from another kernel being compiled)."""
    from numba.core import sigutils
    from numba.core.compiler_lock import global_compiler_lock

    compile_ = type(dispatcher).compile.__get__(dispatcher)
    cache = dispatcher._cache
    lock = Path(cache.cache_path) / f"{cache._impl.filename_base}.lock"
    name = f"{dispatcher.py_func.__module__}.{dispatcher.py_func.__qualname__}"

    def compile(sig):
        args, _ = sigutils.normalize_signature(sig)
        if tuple(args) in dispatcher.overloads:
            return compile_(sig)
        with global_compiler_lock, _machine_lock(lock, name):
            return compile_(sig)

    dispatcher.compile = compile


# ------------------------------------------------------------------ reporting

_reporter: list[Callable[[str], None] | None] = [None]
_told_where = [False]


def report_compiles(log: Callable[[str], None] | None) -> None:
    """Send this process's lines about compiling planner kernels to ``log`` (None: silent, the
    default)."""
    _reporter[0] = log


def _report(message: str) -> None:
    log = _reporter[0]
    if log is not None:
        log(message)
