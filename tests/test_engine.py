"""sfa.engine / sfa.engine_build: the compiled engine computes the JIT's bits, without numba."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import pytest

from sfa import engine

ROOT = Path(__file__).resolve().parent.parent

#: runs in a child process: the listener's pipeline on the datagrams in argv[1] (pickled), with
#: whatever engine SFA_ENGINE asks for; prints the outputs' hashes, the engine, whether numba loaded,
#: and on the JIT the kernels that had to compile after the listener's warm-up (none should)
CHILD = r"""
import hashlib, importlib, json, pickle, sys
from sfa import engine
engine.prefer_compiled()
from listener.config import load_config
from listener.pipeline import Pipeline
from sfa.engine_build import jit_entry_points
from track_db import TrackDatabase

def overloads():
    if engine.is_compiled():
        return {}
    from numba.core.registry import CPUDispatcher
    return {f"{m}.{k}": len(v.overloads) for m in engine.MODULES
            for k, v in vars(importlib.import_module(m)).items() if isinstance(v, CPUDispatcher)}

out, before = {}, None
for name, track, sets, dgrams in pickle.loads(open(sys.argv[1], "rb").read()):
    p = Pipeline(TrackDatabase.open(track), load_config(None, sets), start_epoch=0)
    p.filter.warm_up()
    if before is None:  # what ListenerService.run does before READY
        jit_entry_points()
        before = overloads()
    h, n = hashlib.sha256(), 0
    for payload, port, t in dgrams:
        for o in p.receive(payload, ("127.0.0.1", port), t):
            h.update(o)
            n += 1
    for o in p.flush(dgrams[-1][2] + 10.0):
        h.update(o)
        n += 1
    out[name] = [n, h.hexdigest()]
after = overloads()
late = sorted(k for k in after if after[k] > before.get(k, 0))
print(json.dumps({"runs": out, "engine": engine.active(), "numba": "numba" in sys.modules,
                  "llvmlite": "llvmlite" in sys.modules, "compiled_after_warm_up": late}))
"""


def _env(**extra) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.update(extra)
    return env


@pytest.fixture(scope="module")
def engine_dir(tmp_path_factory) -> Path:
    """A directory holding the compiled engine of the current sources (built here unless installed)."""
    found = engine.find_compiled()
    if found is not None:
        return found.parent
    from sfa.engine_build import build

    out = tmp_path_factory.mktemp("engine")
    build(out)
    return out


def _streams(tmp_path: Path):
    """Simulated streams through the listener's paths (junctions, GNSS loss and faults, standstill,
    RTK) and the real Dresden drive converted to a capture (tools/data/dresden)."""
    from interface_modules.offline import generate
    from interface_modules.scenario import load_scenario
    from interface_modules.tracks import database_path
    from tools.adapters.dresden import convert_dresden
    from tools.capture_reader import read_capture

    items = []
    for name in ("tram-urban", "field-ring", "regional-tunnel", "tram-faults", "standstill-creep",
                 "tram-urban-rtk"):
        sc = load_scenario(name)
        run = generate(sc, max_duration_s=240.0)
        sets = [f"filter.odometer={sc.odometer.preset}", f"filter.imu={sc.imu.preset}",
                f"filter.gps={sc.gps.preset}"]
        items.append((name, str(database_path(sc)), sets,
                      [(p.payload, p.src_port, p.arrival_s) for p in run.packets]))
    conv = tmp_path / "dresden"
    convert_dresden(None, conv)
    dgrams = [(d.payload, d.src[1], d.time_s) for d in read_capture(conv / "capture.pcap", 48000)]
    items.append(("dresden", str(conv / "track.db"), [], dgrams))
    return items


def _child(data: Path, **env) -> dict:
    proc = subprocess.run([sys.executable, "-c", CHILD, str(data)], capture_output=True, text=True,
                          env=_env(**env), timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_compiled_engine_gives_the_jit_outputs_bit_for_bit_without_numba(engine_dir, tmp_path):
    data = tmp_path / "streams.pickle"
    streams = _streams(tmp_path)
    data.write_bytes(pickle.dumps(streams))
    compiled = _child(data, SFA_ENGINE="compiled", SFA_ENGINE_DIR=str(engine_dir))
    jit = _child(data, SFA_ENGINE="jit")
    assert compiled["engine"].startswith("compiled"), compiled["engine"]
    assert not compiled["numba"] and not compiled["llvmlite"]
    assert jit["engine"].startswith("jit") and jit["numba"]
    # on the JIT nothing compiles once data flows (a cold cache stalled the listener 21 s on its first
    # datagrams before sfa.engine_build.jit_entry_points joined its warm-up)
    assert jit["compiled_after_warm_up"] == [], jit["compiled_after_warm_up"]
    for name, *_ in streams:
        n, digest = compiled["runs"][name]
        assert n > 100, (name, n)  # the stream produced outputs: the comparison is not vacuous
        assert compiled["runs"][name] == jit["runs"][name], name


def test_a_kernel_missing_from_the_compiled_engine_switches_to_the_jit(engine_dir):
    # seg_index is called only from compiled code, so it is not exported: calling it from Python in a
    # compiled process must still work, on the JIT, with one line saying so
    code = (
        "import sys, numpy as np\n"
        "from sfa import engine\n"
        "assert engine.prefer_compiled(), engine.active()\n"
        "from sfa import kernels as K\n"
        "ts = np.array([0.0, 10.0, 20.0, 30.0])\n"
        "r = [int(K.seg_index(ts, s)) for s in (-1.0, 5.0, 25.0, 99.0)]\n"
        "print(r, engine.is_compiled(), 'numba' in sys.modules, type(K.step_imu).__name__)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                          env=_env(SFA_ENGINE_DIR=str(engine_dir)))
    assert proc.returncode == 0, proc.stderr[-2000:]
    import numpy as np

    from sfa import kernels as K  # this process: the JIT

    ts = np.array([0.0, 10.0, 20.0, 30.0])
    want = [int(K.seg_index(ts, s)) for s in (-1.0, 5.0, 25.0, 99.0)]
    assert proc.stdout.split("]")[0] + "]" == str(want)
    assert proc.stdout.split("]")[1].split() == ["False", "True", "CPUDispatcher"]
    assert "sfa.kernels.seg_index is not in the compiled engine: numba JIT from here on" in proc.stderr


def test_the_engine_key_follows_every_engine_source_and_the_numba_version(tmp_path, monkeypatch):
    pkg = tmp_path / "sfa"
    pkg.mkdir()
    for name in engine.SOURCES:
        (pkg / name).parent.mkdir(parents=True, exist_ok=True)  # (../listener/clock_core.py too)
        (pkg / name).write_bytes((ROOT / "sfa" / name).read_bytes())
    monkeypatch.setattr(engine, "_package_dir", lambda: pkg)
    base = engine.engine_key("0.68.1", "0.50.0")
    assert base == engine.engine_key("0.68.1", "0.50.0")
    assert engine.engine_key("0.69.0", "0.50.0") != base
    assert engine.engine_key("0.68.1", "0.51.0") != base
    for name in engine.SOURCES:
        src = pkg / name
        orig = src.read_bytes()
        src.write_bytes(orig + b"\n")
        assert engine.engine_key("0.68.1", "0.50.0") != base, name
        src.write_bytes(orig)
    assert engine.find_compiled(base) is None  # nothing built for it: the JIT is used


def test_sources_cover_every_sfa_module_the_kernels_import():
    import ast

    for mod in engine.MODULES:
        tree = ast.parse((ROOT / (mod.replace(".", "/") + ".py")).read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                if name == "sfa.engine":  # the loader: its njit is not compiled into the kernels
                    continue
                if name.startswith("sfa.") and (ROOT / (name.replace(".", "/") + ".py")).is_file():
                    assert engine.source_of(name) in engine.SOURCES, name


def test_entry_points_name_kernels_of_the_engine_modules():
    import importlib

    from sfa import engine_build

    assert {m for m, _ in engine_build.ENTRY_POINTS} <= set(engine.MODULES)
    for mod in engine.MODULES:  # an exported module's source is in the key, or a stale engine could load
        assert engine.source_of(mod) in engine.SOURCES, mod
        assert (ROOT / "sfa" / engine.source_of(mod)).resolve() == ROOT / (mod.replace(".", "/") + ".py")
    for (mod, name), spec in engine_build.ENTRY_POINTS.items():
        disp = getattr(importlib.import_module(mod), name)
        assert hasattr(disp, "py_func"), (mod, name)
        n_args = disp.py_func.__code__.co_argcount
        assert len(spec.split()) == n_args, (mod, name, spec)


def test_unknown_engine_mode_is_one_line_and_falls_back(tmp_path):
    proc = subprocess.run([sys.executable, "-c", "from sfa import engine; print(engine.active())"],
                          capture_output=True, text=True, env=_env(SFA_ENGINE="fast"), timeout=60)
    assert proc.returncode == 0
    assert proc.stdout.startswith("jit (")
    assert proc.stderr.strip() == "sfa: SFA_ENGINE='fast' is not jit, compiled or auto: using auto"



def test_listen_refuses_to_start_without_the_engine_when_it_is_required(tmp_path):
    import shutil

    # a copy of the sfa and listener packages (the engine's sources) whose engine sources differ by one
    # byte: no engine was built for them
    for pkg in ("sfa", "listener"):
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("_engine_*", "__pycache__"))
    src = tmp_path / "sfa" / "engine_build.py"
    src.write_text(src.read_text() + "\n")
    env = _env(SFA_ENGINE="compiled")
    env["PYTHONPATH"] = f"{tmp_path}{os.pathsep}{env['PYTHONPATH']}"
    env.pop("SFA_ENGINE_DIR", None)
    proc = subprocess.run([sys.executable, "-m", "sfa", "listen", "--port", "0", "--bind", "127.0.0.1"],
                          capture_output=True, text=True, env=env, timeout=120, cwd=tmp_path)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    want = "sfa listen: error: SFA_ENGINE=compiled but no compiled engine is usable: jit (no compiled engine"
    assert lines[0].startswith(want), lines[0]
