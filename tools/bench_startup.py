"""Start-up rows of ``sfa bench``: ``sfa listen``'s cold first output and peak RSS, compiled engine
against the JIT (the previous start) on an empty and on a warm numba cache.

The measurement is benchmarks/bench_startup.py (a real ``sfa listen`` process fed by a real simulated
stream at 1x, each start on a fresh, empty numba cache directory; see its docstring).
"""

from __future__ import annotations

from tools.bench_table import Row

SECTION = "startup"


def startup_rows(repeats: int, quick: bool, log=print) -> list[Row]:
    from tools.bench_replay import load_benchmark_module

    bs = load_benchmark_module("bench_startup")
    seconds = 3.0 if quick else 8.0
    s = bs.summary(bs.measure(bs.SCENARIO, seconds, repeats, log=log))
    c, jc, jw = s["compiled"], s["jit_cold"], s["jit_warm"]
    note = "" if str(c["engine"]).startswith("compiled") else (
        f"the compiled start ran on {c['engine']}: no compiled engine for these sources "
        "(python -m sfa.engine_build builds it; pip install does)"
    )

    def ratio(a, b):
        return "-" if a is None or not b else f"{a / b:.1f}x"

    def fmt(v, unit):
        return "-" if v is None else f"{v:.2f} {unit}"

    fo = c["first_output_s"]
    rss = c["peak_rss_mib"]
    fresh = c["cache_files_at_spawn"] == 0 and jc["cache_files_at_spawn"] == 0
    cache = (
        f"numba cache empty at spawn in every cold start: {fresh} (files at spawn: compiled "
        f"{c['cache_files_at_spawn']}, JIT cold {jc['cache_files_at_spawn']}; the JIT cold start wrote "
        f"{'/'.join(str(n) for n in jc['cache_files_after'])} files there, the compiled start "
        f"{'/'.join(str(n) for n in c['cache_files_after'])})"
    )
    if not fresh:
        stale = "a cold start did not begin on an empty cache: not a cold figure"
        note = f"{note}; {stale}" if note else stale
    return [
        Row(
            SECTION,
            f"sfa listen first output after spawn, empty numba cache ({bs.SCENARIO} at 1x, compiled engine)",
            fo,
            "s",
            compared=f"JIT on an empty cache (the previous start) {fmt(jc['first_output_s'], 's')} "
            f"({ratio(jc['first_output_s'], fo)} the compiled), JIT on a warm cache "
            f"{fmt(jw['first_output_s'], 's')} ({ratio(jw['first_output_s'], fo)}); port bound at "
            f"{fmt(c['bound_s'], 's')}; {cache}",
            target=f"<= {bs.TARGET_FIRST_OUTPUT_S:g} s",
            met=None if fo is None or not fresh else fo <= bs.TARGET_FIRST_OUTPUT_S,
            note=note,
            repeats=repeats,
            samples=tuple(v for v in c["samples_first_output_s"] if v is not None),
        ),
        Row(
            SECTION,
            f"sfa listen peak RSS over {seconds:g} s of streaming from spawn (VmHWM, compiled engine)",
            rss,
            "MiB",
            compared=f"JIT on an empty cache {fmt(jc['peak_rss_mib'], 'MiB')} "
            f"({ratio(jc['peak_rss_mib'], rss)} the compiled), JIT on a warm cache "
            f"{fmt(jw['peak_rss_mib'], 'MiB')} "
            f"({ratio(jw['peak_rss_mib'], rss)}); started on an empty numba cache: {fresh}",
            target="<= 150 MB (143.1 MiB)",
            met=None if rss is None or not fresh else rss <= bs.TARGET_PEAK_RSS_MIB,
            note=note,
            repeats=repeats,
            samples=tuple(v for v in c["samples_peak_rss_mib"] if v is not None),
        ),
    ]
