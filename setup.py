"""Build step of the compiled engine (everything else is in pyproject.toml).

``pip install`` (a wheel, or ``pip install -e .``) compiles the filter kernels ahead of time into
``sfa/_engine_<key>`` (sfa.engine_build, numba.pycc), so ``sfa listen`` starts without numba's JIT:
first output about 1 s after spawn instead of about 20 s on an empty cache, and a third of the
memory (docs/performance.md, "Start-up and footprint"). The build needs numba (a build requirement)
and a C compiler; if it fails the install still succeeds, with a warning, and the listener runs on
the JIT as before. ``SFA_ENGINE_BUILD=0`` skips it.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent


def _engine_extensions() -> list[Extension]:
    if os.environ.get("SFA_ENGINE_BUILD", "1") == "0":
        return []
    sys.path.insert(0, str(ROOT))
    try:
        from sfa import engine

        key = engine.engine_key()  # the numba/llvmlite of this build environment
    except Exception as exc:  # noqa: BLE001 - never fail the install for the optional engine
        print(f"warning: sfa compiled engine not built ({exc}); sfa listen will use numba's JIT",
              file=sys.stderr)
        return []
    finally:
        sys.path.pop(0)
    # no sources: build_extension below makes the module; optional: a failed build is tolerated
    return [Extension(f"sfa.{engine.module_name(key)}", sources=[], optional=True)]


class BuildExt(build_ext):
    def build_extension(self, ext: Extension) -> None:
        if not ext.name.startswith("sfa._engine_"):
            super().build_extension(ext)
            return
        out_dir = Path(self.get_ext_fullpath(ext.name)).parent
        sys.path.insert(0, str(ROOT))
        try:
            from sfa.engine_build import build

            print(f"building the sfa compiled engine into {out_dir} (about 30 s)", file=sys.stderr)
            path = build(out_dir)
            print(f"built {path}", file=sys.stderr)
        except Exception as exc:  # noqa: BLE001 - the engine is optional: warn, install anyway
            print(f"warning: sfa compiled engine not built: {exc}\n"
                  "sfa listen will use numba's JIT (rebuild: python -m sfa.engine_build)", file=sys.stderr)
        finally:
            sys.path.pop(0)


setup(ext_modules=_engine_extensions(), cmdclass={"build_ext": BuildExt})
