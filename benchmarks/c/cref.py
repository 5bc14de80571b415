"""Build and call the C reference of the SFA filter step (benchmarks/c/sfa_step.c) through ctypes.

``build()`` writes ``sfa_layout.h`` from :mod:`sfa.layout` (every slot index the kernels use, so the C
code and the Python layout cannot drift), compiles ``sfa_step.c`` with the system C compiler at
``-O2`` into a shared library in a cache directory keyed by the sources' hash, and loads it.
When no C compiler is found it raises :class:`CReferenceUnavailable` with the reason (the bench
prints it and skips the comparison). ``run_packed`` has the signature and outputs of
``sfa.batch.run_packed``.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "sfa_step.c"
CFLAGS = ("-O2", "-fPIC", "-shared", "-std=c99")
_PREFIXES = ("A_", "C_", "K_", "R_", "MEM_")
_NAMES = (
    "S",
    "V",
    "BA",
    "KO",
    "GE",
    "GN",
    "BG",
    "MY",
    "SF",
    "SG",
    "MX",
    "NX",
    "NAUX",
    "NCNT",
    "NCFG",
    "NMEM",
    "NH",
    "SNAP",
    "FAULT_REASONS",
)


class CReferenceUnavailable(RuntimeError):
    """No C compiler, or the build failed: the C reference is skipped (the message says why)."""


def layout_header() -> str:
    """``#define`` lines for every integer slot of sfa.layout the C code uses, the adaptive GNSS model's
    layout constants and sfa.gnss_noise's constants (GN_*), NVALS, COS_MAX_ROLL and the GNSS update's
    GPS_IEKF_* (sfa.kernels); floats written with repr: the same doubles."""
    from sfa import layout
    from sfa.batch import NV

    lines = [
        "/* generated from sfa/layout.py by benchmarks/c/cref.py: do not edit */",
        "#ifndef SFA_LAYOUT_H",
        "#define SFA_LAYOUT_H",
    ]
    for name in sorted(vars(layout)):
        value = getattr(layout, name)
        if type(value) is int and (name in _NAMES or name.startswith(_PREFIXES + ("AD_",))):
            lines.append(f"#define {name} {value}")
        elif name.startswith("AD_") and type(value) is float:
            lines.append(f"#define {name} {value!r}")
        elif name.startswith("AD_") and type(value) is tuple:
            lines.append(f"static const double {name}[] = {{{', '.join(repr(float(v)) for v in value)}}};")
    from sfa import gnss_noise

    # the adaptive GNSS model's constants, written with repr (the same doubles), prefixed GN_
    for name in ("LAG_TOL_S", "MIN_NORMAL_DOT", "MIN_PAIR_DISTANCE_M", "CLIP_SIGMA", "FLOOR_GM",
                 "FLOOR_WHITE", "CEILING", "TAU_MIN_S", "TAU_N", "NR"):
        lines.append(f"#define GN_{name} {getattr(gnss_noise, name)!r}")
    from sfa.kernels import (
        COS_MAX_ROLL,
        GPS_IEKF_ITERATIONS,
        GPS_IEKF_TOL_M,
        GYRO_LAM_MAX,
        GYRO_LAM_PRIOR,
        LAT_NC_MAX,
    )

    lines += [f"#define NVALS {NV}", f"#define COS_MAX_ROLL {COS_MAX_ROLL!r}",
              f"#define GYRO_LAM_MAX {GYRO_LAM_MAX!r}", f"#define GYRO_LAM_PRIOR {GYRO_LAM_PRIOR!r}",
              f"#define GPS_IEKF_ITERATIONS {GPS_IEKF_ITERATIONS}",
              f"#define GPS_IEKF_TOL_M {GPS_IEKF_TOL_M!r}", f"#define LAT_NC_MAX {LAT_NC_MAX!r}",
              "#endif", ""]
    return "\n".join(lines)


def find_compiler() -> str | None:
    """The C compiler: $CC, else cc, gcc or clang on PATH."""
    cc = os.environ.get("CC")
    if cc and shutil.which(cc):
        return shutil.which(cc)
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return path
    return None


def compiler_version(cc: str) -> str:
    try:
        out = subprocess.run([cc, "--version"], capture_output=True, text=True, timeout=10, check=False)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (out.stdout.splitlines() or ["unknown"])[0].strip()


class CReference:
    """The compiled C reference: ``run_packed`` over packed arrays."""

    def __init__(self, lib_path: Path, cc: str) -> None:
        self.path = lib_path
        self.compiler = f"{compiler_version(cc)} {' '.join(CFLAGS[:1])}"
        lib = ctypes.CDLL(str(lib_path))
        fn = lib.sfa_run_packed
        dptr = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")
        lptr = np.ctypeslib.ndpointer(dtype=np.int64, flags="C_CONTIGUOUS")
        fn.restype = ctypes.c_long
        fn.argtypes = [
            ctypes.c_long,
            lptr,
            dptr,
            dptr,
            dptr,
            dptr,
            dptr,
            lptr,
            dptr,
            dptr,
            ctypes.c_long,
            dptr,
            dptr,
            dptr,
            dptr,
            dptr,
            dptr,
            lptr,
        ]
        self._fn = fn

    def run_packed(self, kind, t, vals, x, P, aux, cnt, mem, cfg, ts, te, tn, tg, tk, out_f, out_i) -> None:
        """Same arguments and in-place results as ``sfa.batch.run_packed``."""
        n = int(kind.shape[0])
        for name, arr, shape in (("vals", vals, (n, 7)), ("out_f", out_f, (n, 4)), ("out_i", out_i, (n, 3))):
            if arr.shape != shape:
                raise ValueError(f"{name}: shape {arr.shape}, expected {shape}")
        self._fn(
            n, kind, t, vals, x, P, aux, cnt, mem, cfg, int(ts.shape[0]), ts, te, tn, tg, tk, out_f, out_i
        )


def build(cache_dir: Path | None = None) -> CReference:
    """Compile (once per source hash) and load the C reference; CReferenceUnavailable otherwise."""
    if ctypes.sizeof(ctypes.c_long) != 8:
        raise CReferenceUnavailable("C long is not 64-bit on this platform")
    cc = find_compiler()
    if cc is None:
        raise CReferenceUnavailable("no C compiler found (set CC, or install cc/gcc/clang)")
    header = layout_header()
    src = SOURCE.read_text()
    key = hashlib.sha256((header + src + " ".join(CFLAGS) + cc).encode()).hexdigest()[:16]
    cache = cache_dir or Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "sfa" / "cref"
    lib_path = cache / f"sfa_step-{key}.so"
    if not lib_path.is_file():
        try:
            cache.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CReferenceUnavailable(f"cache directory {cache}: {exc.strerror or exc}") from exc
        with tempfile.TemporaryDirectory() as tmp:
            (Path(tmp) / "sfa_layout.h").write_text(header)
            (Path(tmp) / "sfa_step.c").write_text(src)
            out = Path(tmp) / "sfa_step.so"
            cmd = [cc, *CFLAGS, "-o", str(out), str(Path(tmp) / "sfa_step.c"), "-lm"]
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
            except (OSError, subprocess.SubprocessError) as exc:
                raise CReferenceUnavailable(f"{cc} failed to run: {exc}") from exc
            if proc.returncode != 0:
                raise CReferenceUnavailable(f"{cc} failed: {proc.stderr.strip()[:500]}")
            tmp_target = lib_path.with_suffix(f".{os.getpid()}.tmp")
            shutil.copyfile(out, tmp_target)
            os.replace(tmp_target, lib_path)
    return CReference(lib_path, cc)
