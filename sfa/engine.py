"""How the filter kernels are loaded: numba's JIT, or the same kernels compiled ahead of time.

``sfa.kernels`` and ``sfa.gnss_noise`` decorate their functions with :func:`njit` from here instead of
numba's. In a process that runs on the JIT (the default: replay, tests, benchmarks) it *is* numba's
``njit``: nothing changes. In a process that asked for the compiled engine (``sfa listen`` calls
:func:`prefer_compiled` before it imports the filter), each kernel the Python side calls is the
function of the same name in a native extension module built ahead of time from these very sources by
:mod:`sfa.engine_build` (at install: ``pip install`` runs it, see setup.py); numba and llvmlite are
then never imported, so the process starts in about a second and its resident memory is a fraction
of the JIT's (docs/performance.md, "Start-up and footprint").

The extension's file name carries :func:`engine_key`: a hash of the engine's sources
(:data:`SOURCES`), the numba and llvmlite versions installed and the Python ABI. Edit a kernel, or
install another numba, and the key changes: the stale module is never loaded and the process runs on
the JIT, as before (rebuild with ``python -m sfa.engine_build``). The compiled functions are numba's
own machine code for the same IR with the kernels' own flags (the builder exports thin wrappers that
call the jitted kernels), so the outputs are bit-identical to the JIT's (tests/test_engine.py).

A kernel called from Python that the extension does not export (a new one not yet in
``sfa.engine_build.ENTRY_POINTS``) never fails: the first call switches the process to the JIT (one
line on stderr, :func:`active` says why) and it runs there.

Every sfa module with numba functions that call the kernels decorates them with this :func:`njit`
too (``sfa.batch`` does): on the JIT nothing changes, and in a compiled process their first call
switches to the JIT as above, where numba's ``njit`` would fail to type the compiled kernels. A
module whose kernels are exported must be in :data:`MODULES` and its source in :data:`SOURCES`.

The listener's STROBE clock (:mod:`listener.clock_core`), output guard (:mod:`listener.guard_core`)
and sequence buffers (:mod:`listener.seq_core`) are in the extension too: their kernels are decorated
with this :func:`njit`, and their sources are in the key like the filter's.

``SFA_ENGINE`` overrides the choice: ``jit`` (always the JIT, the previous behaviour, e.g. for the
start-up benchmark's comparison), ``compiled`` (the compiled engine in every process, and required:
``sfa listen`` refuses to start without it, as the systemd unit asks, whose memory limit a JIT
compile would exceed), unset or ``auto`` (compiled where :func:`prefer_compiled` was called and the
engine is there, else the JIT). ``SFA_ENGINE_DIR`` names a
directory searched before the package's own for the extension (tests build one there).

Standard library only at import: this module is imported by ``sfa listen`` before numpy.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import os
import sys
import sysconfig
from pathlib import Path

#: the engine's sources, relative to the sfa package: the kernels and every sfa module they read at
#: compile time (layout constants are frozen into the machine code; the configuration slots K_* are
#: numbered from sfa/config.py's declarations), and the builder's entry points; kernels of another
#: package by their path from here (the listener's STROBE clock, output guard and sequence buffers)
SOURCES = ("kernels.py", "gnss_noise.py", "layout.py", "config.py", "separation.py", "bank.py",
           "engine_build.py", "../listener/clock_core.py", "../listener/guard_core.py",
           "../listener/seq_core.py")
#: the modules whose ``@njit`` functions the extension carries
MODULES = ("sfa.kernels", "sfa.gnss_noise", "sfa.separation", "sfa.bank", "listener.clock_core",
           "listener.guard_core", "listener.seq_core")
PREFIX = "_engine_"  #: extension module name: PREFIX + engine_key()
ENV_MODE = "SFA_ENGINE"
ENV_DIR = "SFA_ENGINE_DIR"

_state: dict = {"mode": None, "module": None, "path": None, "reason": "", "fallback": ""}
_registry: list[_Kernel] = []  # every function decorated here, in order


def _package_dir() -> Path:
    return Path(__file__).resolve().parent


def source_of(module: str) -> str:
    """The :data:`SOURCES` entry of a module's file (``sfa.kernels`` -> ``kernels.py``,
    ``listener.clock_core`` -> ``../listener/clock_core.py``)."""
    pkg, rest = module.split(".", 1)
    path = rest.replace(".", "/") + ".py"
    return path if pkg == "sfa" else f"../{pkg}/{path}"


def _dist_version(name: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "none"


def engine_key(numba_version: str | None = None, llvmlite_version: str | None = None) -> str:
    """16 hex digits naming the extension built from these sources with these numba/llvmlite versions."""
    h = hashlib.sha256()
    root = _package_dir()
    for name in SOURCES:
        h.update(name.encode() + b"\0" + (root / name).read_bytes() + b"\0")
    h.update(f"numba={numba_version or _dist_version('numba')};".encode())
    h.update(f"llvmlite={llvmlite_version or _dist_version('llvmlite')};".encode())
    h.update(f"abi={sysconfig.get_config_var('EXT_SUFFIX')};".encode())
    return h.hexdigest()[:16]


def module_name(key: str | None = None) -> str:
    return PREFIX + (key or engine_key())


def export_name(module: str, name: str) -> str:
    """The extension's symbol for ``module.name`` (``sfa.kernels.step_imu`` -> ``kernels__step_imu``)."""
    return f"{module.rsplit('.', 1)[-1]}__{name}"


def _search_dirs() -> list[Path]:
    dirs = [Path(d) for d in os.environ.get(ENV_DIR, "").split(os.pathsep) if d]
    return dirs + [_package_dir()]


def find_compiled(key: str | None = None) -> Path | None:
    """The extension file for the current sources, or None when none was built for them."""
    fname = module_name(key) + (sysconfig.get_config_var("EXT_SUFFIX") or ".so")
    for d in _search_dirs():
        if (d / fname).is_file():
            return d / fname
    return None


def _load_compiled() -> object | None:
    try:
        key = engine_key()
    except OSError as exc:  # a source missing (a stripped install): no compiled engine
        _state["reason"] = f"engine sources unreadable ({exc})"
        return None
    path = find_compiled(key)
    if path is None:
        _state["reason"] = f"no compiled engine {module_name(key)} (build it: python -m sfa.engine_build)"
        return None
    name = f"sfa.{module_name(key)}"
    try:
        loader = importlib.machinery.ExtensionFileLoader(name, str(path))
        spec = importlib.util.spec_from_file_location(name, str(path), loader=loader)
        mod = importlib.util.module_from_spec(spec)
        loader.exec_module(mod)
    except (ImportError, OSError) as exc:
        _state["reason"] = f"compiled engine {path} not loadable: {exc}"
        return None
    _state["path"] = str(path)
    return mod


def _mode() -> str:
    """'compiled' or 'jit', fixed by the first kernel decorated in this process."""
    if _state["mode"] is None:
        want = os.environ.get(ENV_MODE, "auto").strip().lower()
        if want == "jit":
            _state["reason"] = f"{ENV_MODE}=jit"
            _state["mode"] = "jit"
        elif want == "compiled" or (want in ("auto", "") and _state.get("preferred")):
            _state["module"] = _load_compiled()
            _state["mode"] = "compiled" if _state["module"] is not None else "jit"
        else:
            if want not in ("auto", ""):
                print(f"sfa: {ENV_MODE}={want!r} is not jit, compiled or auto: using auto", file=sys.stderr)
            _state["reason"] = "JIT by default outside sfa listen"
            _state["mode"] = "jit"
    return _state["mode"]


def prefer_compiled() -> bool:
    """Ask for the compiled engine in this process (before ``sfa.kernels`` is imported); True if it
    will be used. Without it (or after the kernels were imported on the JIT) the JIT is used."""
    if _state["mode"] is None:
        _state["preferred"] = True
    return _mode() == "compiled"


def required() -> bool:
    """``SFA_ENGINE=compiled``: a process that cannot load the compiled engine must not start."""
    return os.environ.get(ENV_MODE, "").strip().lower() == "compiled"


def active() -> str:
    """What this process runs the kernels on, in words (for the listener's start-up log)."""
    mode = _mode()
    if mode == "compiled" and not _state["fallback"]:
        return f"compiled ({Path(_state['path']).name})"
    return f"jit ({_state['fallback'] or _state['reason']})"


def is_compiled() -> bool:
    """The kernels run from the compiled extension (and numba was not needed so far)."""
    return _mode() == "compiled" and not _state["fallback"]


class _Kernel:
    """A decorated function in compiled mode that the extension does not carry: its first call
    switches the process to the JIT."""

    def __init__(self, fn, args: tuple, options: dict) -> None:
        self.fn, self.args, self.options = fn, args, options
        self.dispatcher = None
        self.__name__ = fn.__name__
        self.__qualname__ = fn.__qualname__
        self.__doc__ = fn.__doc__
        self.__module__ = fn.__module__
        self.__wrapped__ = fn

    def __call__(self, *a):
        if self.dispatcher is None:
            _switch_to_jit(f"{self.fn.__module__}.{self.fn.__name__} is not in the compiled engine")
        return self.dispatcher(*a)


def _switch_to_jit(reason: str) -> None:
    """Make every decorated function a numba dispatcher, rebound in its module (the compiled
    functions already handed out stay valid: they compute the same bits)."""
    import numba

    _state["fallback"] = reason
    print(f"sfa: {reason}: numba JIT from here on", file=sys.stderr)
    for k in _registry:
        k.dispatcher = numba.njit(*k.args, **k.options)(k.fn)
    for k in _registry:
        k.fn.__globals__[k.fn.__name__] = k.dispatcher


def njit(*args, **options):
    """``numba.njit`` on the JIT; in compiled mode, the extension's function of the same name."""
    if len(args) == 1 and callable(args[0]) and not options:
        return njit()(args[0])

    def decorate(fn):
        if _mode() == "jit":
            import numba

            return numba.njit(*args, **options)(fn)
        k = _Kernel(fn, args, options)
        _registry.append(k)
        compiled = getattr(_state["module"], export_name(fn.__module__, fn.__name__), None)
        return compiled if compiled is not None else k

    return decorate
