"""Build the compiled engine: the kernels the Python side calls, compiled ahead of time (numba.pycc).

``python -m sfa.engine_build [--out-dir DIR]`` writes ``_engine_<key>`` (a native extension module,
see :mod:`sfa.engine`) into the sfa package directory, or DIR. ``pip install`` runs it (setup.py's
build_ext), so an installed project starts ``sfa listen`` without compiling anything.

Each entry point is exported as a thin wrapper that calls the numba dispatcher of the kernel: numba
compiles the kernel with its own flags (``_nrt``, ``error_model``, inlining) exactly as the JIT does,
and pycc links that code into the extension, so the extension computes the same bits as the JIT
(tests/test_engine.py compares the listener's outputs on every shipped scenario). The JIT compile
runs with ``NUMBA_SLP_VECTORIZE=1`` as ``sfa`` sets it, in a child process with an empty private
cache, so nothing stale can leak in. Needs numba and a C compiler (pycc links a small C runtime).

:data:`ENTRY_POINTS` lists every kernel called from Python (sfa.filter, sfa.bank, the listener's clock,
output guard and sequence buffers) with its argument types: contiguous float64 vectors (A1), matrices
(A2) and 3-d arrays (A3), int64 vectors (I1) and matrices (I2), and scalars.
A kernel missing here still works in a compiled process (its first call switches to the JIT).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: (module, kernel) -> argument types, in the letters below (a kernel's return type is numba's)
ENTRY_POINTS: dict[tuple[str, str], str] = {
    ("sfa.kernels", "step_init"): "A1 A2 A1 I1 A1 A1 A1 A1 f8 f8 f8 f8",
    ("sfa.kernels", "step_imu"): "A1 A2 A1 I1 A1 A1 A1 A1 A1 f8 f8 f8 f8 f8 f8 f8",
    ("sfa.kernels", "step_odo"): "A1 A2 A1 I1 A1 A1 A1 A1 f8 f8 f8",
    ("sfa.kernels", "step_gps"): "A1 A2 A1 I1 A1 A1 A1 A1 A1 f8 f8 f8 f8 i8",
    ("sfa.kernels", "status_of"): "A1 A2 A1 A1 f8",
    ("sfa.kernels", "predict_to"): "A1 A2 A1 I1 A1 A1 A1 f8",
    ("sfa.kernels", "sync_block"): "A1 A2 A1 A1 I1",
    ("sfa.kernels", "restart_gnss_error"): "A1 A2 A1",
    ("sfa.kernels", "mirror"): "A1 A2 A1",
    ("sfa.kernels", "pending_var_v"): "A2 A1",
    ("sfa.kernels", "interp_at"): "A1 A1 f8",
    ("sfa.kernels", "geom_at"): "A1 A1 A1 f8",
    ("sfa.gnss_noise", "share"): "A1 A1 b1",
    ("listener.clock_core", "on_strobe"): "A1 f8 f8",
    ("listener.clock_core", "offset_at"): "A1 f8",
    ("listener.clock_core", "sensor_time"): "A1 f8",
    ("listener.guard_core", "check"): "A1 I1 i8 f8 f8",
    ("listener.guard_core", "sent"): "A1 I1 b1 i8 f8 f8 f8",
    ("listener.seq_core", "init_slot"): "I2 A2 A1 I1 i8",
    ("listener.seq_core", "push"): "I2 A2 A1 I1 I1 I1 A2 i8 i8 i8 f8",
    ("listener.seq_core", "poll"): "I2 A2 A1 I1 I1 I1 A2 i8 f8",
    ("listener.seq_core", "next_deadline"): "I2 A2 A1 i8",
    ("listener.seq_core", "reopen"): "I2 A1 i8 i8",
    ("listener.seq_core", "flush"): "I2 A2 A1 I1 I1 I1 i8",
    ("listener.seq_core", "footprint"): "I2 A1 i8",
    ("listener.seq_core", "table_push"): "I2 A2 A1 I1 I1 I1 A2 i8 i8 i8 i8 f8",
    ("listener.seq_core", "table_next_deadline"): "I2 A2 A1 I1",
    ("listener.seq_core", "table_poll"): "I2 A2 A1 I1 I1 I1 A2 f8",
    ("listener.seq_core", "table_flush"): "I2 A2 A1 I1 I1 I1",
    ("sfa.bank", "run_segment"): "I1 A1 A2 i8 b1 A2 A3 A2 I2 A2 I2 I1 I1 A1 A2 I1 A1 I1 A1 I1 A1 "
                                 "A2 A3 A2 I2 A2 A2 A1 I1 A1 A1 A1 A1 A2 I2 I1 i8",
    ("sfa.bank", "prune"): "I1 I1 A2 A2 I2 A2 I1 A1 A1 I1 A1",
    ("sfa.bank", "emit"): "i8 A2 A3 A2 I2 I1 I1 A1 I1 A1 A1 A1 A2 I2 I1 i8 A1",
    ("sfa.bank", "status"): "I1 i8 A2 A3 A2 I2 A1 i8 f8 A1",
    ("sfa.bank", "same_track"): "i8 i8 A2 A2 I2 A2 I1 f8",
    ("sfa.bank", "twin"): "I1 i8 A2 A2 I2 i8",
    ("sfa.bank", "empty_gyro_windows"): "I1 i8 A2",
    ("sfa.bank", "_copy_slot"): "i8 i8 A2 A3 A2 I2 A2 I2 b1",
}


def _types():
    from numba import types as T

    return {"A1": T.float64[::1], "A2": T.float64[:, ::1], "A3": T.float64[:, :, ::1], "I1": T.int64[::1],
            "I2": T.int64[:, ::1], "f8": T.float64, "i8": T.int64, "b1": T.boolean}


def _signature(spec: str) -> tuple:
    types = _types()
    return tuple(types[s] for s in spec.split())


def jit_entry_points() -> int:
    """On the JIT, compile (or load from numba's cache) every entry point for its signature, as the
    compiled engine holds them, so that nothing is left to compile when data arrives: a kernel first
    called by live data otherwise stalls the service for seconds on a cold cache (the listener's
    sequence buffers, clock and output guard took 21 s on the first datagrams). Returns how many; 0 in
    a compiled process."""
    import importlib

    from sfa import engine

    if engine.is_compiled():
        return 0
    for (mod_name, name), spec in ENTRY_POINTS.items():
        getattr(importlib.import_module(mod_name), name).compile(_signature(spec))
    return len(ENTRY_POINTS)


def _compile(out_dir: Path, verbose: bool) -> Path:
    """In this process (numba not yet imported, SLP set): JIT every entry point, export, link."""
    import importlib
    import warnings

    import llvmlite
    import numba

    warnings.filterwarnings("ignore", message=".*pycc.*")  # numba's pending-deprecation notice
    from numba.pycc import CC

    from sfa import engine

    key = engine.engine_key(numba.__version__, llvmlite.__version__)
    cc = CC(engine.module_name(key))
    cc.output_dir = str(out_dir)
    cc.verbose = verbose
    t0 = time.perf_counter()
    for (mod_name, name), spec in ENTRY_POINTS.items():
        disp = getattr(importlib.import_module(mod_name), name)
        args = _signature(spec)
        disp.compile(args)
        ret = disp.overloads[args].signature.return_type
        ns = {"_kernel": disp}
        params = ", ".join(f"a{i}" for i in range(len(args)))
        exec(f"def {name}({params}):\n    return _kernel({params})\n", ns)  # noqa: S102 - generated
        cc.export(engine.export_name(mod_name, name), ret(*args))(ns[name])
        if verbose:
            print(f"  {mod_name}.{name} -> {ret} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    cc.compile()
    built = out_dir / cc.output_file
    for old in out_dir.glob(engine.PREFIX + "*"):  # engines of earlier sources: never loaded again
        if old != built and old.name.endswith(built.name[len(cc.name):]):
            old.unlink(missing_ok=True)
    return built


def build(out_dir: Path | None = None, verbose: bool = False, python: str | None = None) -> Path:
    """Build the extension for the current sources into ``out_dir`` (default: the sfa package) in a
    child process; returns its path. Raises RuntimeError with the child's output on failure."""
    out = Path(out_dir) if out_dir is not None else Path(__file__).resolve().parent
    out.mkdir(parents=True, exist_ok=True)
    root = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory(prefix="sfa-engine-cache-") as cache:
        env = dict(os.environ)
        env.update(NUMBA_CACHE_DIR=cache, NUMBA_SLP_VECTORIZE="1", SFA_ENGINE="jit")
        env["PYTHONPATH"] = str(root) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        cmd = [python or sys.executable, "-m", "sfa.engine_build", "--child", "--out-dir", str(out)]
        if verbose:
            cmd.append("--verbose")
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=str(root))
    if verbose and proc.stderr:
        print(proc.stderr, end="", file=sys.stderr)
    if proc.returncode != 0:
        raise RuntimeError(f"compiled engine build failed: {(proc.stderr or proc.stdout).strip()[-2000:]}")
    return Path(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sfa.engine_build", description=__doc__.split("\n")[0])
    ap.add_argument("--out-dir", help="where to write the extension (default: the sfa package directory)")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(_compile(Path(args.out_dir), args.verbose))
        return 0
    t0 = time.perf_counter()
    try:
        path = build(Path(args.out_dir) if args.out_dir else None, verbose=args.verbose)
    except RuntimeError as exc:
        print(f"sfa.engine_build: {exc}", file=sys.stderr)
        return 1
    print(f"{path} ({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
