"""tools.fast_loop's disk cache: keyed on the sources its loop is compiled from (sfa/*.py and itself)."""

from __future__ import annotations

from pathlib import Path

import numba

import sfa
import tools.fast_loop as fl


def test_the_key_changes_with_any_source(tmp_path):
    a, b = tmp_path / "kernels.py", tmp_path / "layout.py"
    a.write_text("X = 1\n")
    b.write_text("K_Z = 3\n")
    key = fl.source_key([a, b])
    assert fl.source_key([a, b]) == key  # deterministic
    b.write_text("K_Z = 4\n")  # a layout slot moved
    assert fl.source_key([a, b]) != key
    b.write_text("K_Z = 3\n")
    assert fl.source_key([a, b]) == key
    assert fl.source_key([b, a]) != key  # names and order are part of it


def test_the_loops_are_cached_under_the_current_key():
    sources = [*sorted(Path(sfa.__file__).parent.glob("*.py")), Path(fl.__file__)]
    assert fl.CACHE_DIR is not None  # the worktree's __pycache__ (or NUMBA_CACHE_DIR) is writable
    assert Path(fl.CACHE_DIR).name == f"fast_loop-{fl.source_key(sources)}"
    for func in (fl.run_replay_loop,):
        assert func._cache._cache_path.startswith(fl.CACHE_DIR), func
    assert numba.config.CACHE_DIR != fl.CACHE_DIR  # put back for every other module
