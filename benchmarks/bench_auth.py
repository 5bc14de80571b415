"""Cost of the authenticated-link extension per datagram, measured side by side in one run.

    /work/.venv/bin/python benchmarks/bench_auth.py [--n 200000] [--repeat 3]

Per INPUT datagram (IMU with epoch, 61 bytes; the most frequent datagram, 100 per second per train):

1. ``decode_input`` alone: what the listener does today for every datagram (the reference);
2. ``unwrap`` (HMAC-SHA256 truncated to 128 bits, constant-time compare, replay window) alone;
3. ``unwrap`` + ``decode_input``: the listener's receive path with authentication on;
4. ``wrap``: the sender's cost;
5. ``unwrap`` of forgeries (wrong tag): the cost an attacker can impose per datagram.

Rates are the best of ``--repeat`` runs (time.perf_counter); the ratios say how much slower the
authenticated path is than decoding alone. Inputs are seeded (numpy.random.default_rng(1)).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from listener.auth import AuthState, EpochCounter, derive_link_key, input_seq, unwrap, wrap
from listener.codec import ImuSample, decode_input, encode_input


def best_us(fn, n: int, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=200_000, help="datagrams per measurement")
    ap.add_argument("--repeat", type=int, default=3, help="runs per measurement (best is kept)")
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    key = derive_link_key(rng.bytes(32), "modules->listener")
    counter = EpochCounter()
    plain = []
    for i in range(args.n):
        f = rng.normal(0.0, 0.5, 6)
        plain.append(encode_input(ImuSample(i & 0xFFFF, *map(float, f), 1.7e9 + i * 0.01)))
    wrapped = [wrap(p, key, counter.epoch_for(input_seq(p))) for p in plain]
    forged = [w[:-16] + rng.bytes(16) for w in wrapped[: args.n // 4]]
    sender = ("127.0.0.1", 47001)

    def run_decode():
        for p in plain:
            decode_input(p)

    def run_unwrap():
        state = AuthState()
        for w in wrapped:
            unwrap(w, key, state, sender)

    def run_both():
        state = AuthState()
        for w in wrapped:
            decode_input(unwrap(w, key, state, sender))

    def run_wrap():
        c = EpochCounter()
        for p in plain:
            wrap(p, key, c.epoch_for(input_seq(p)))

    def run_forged():
        state = AuthState()
        for f in forged:
            try:
                unwrap(f, key, state, sender)
            except Exception:
                pass

    dec = best_us(run_decode, args.n, args.repeat)
    unw = best_us(run_unwrap, args.n, args.repeat)
    both = best_us(run_both, args.n, args.repeat)
    wr = best_us(run_wrap, args.n, args.repeat)
    fo = best_us(run_forged, len(forged), args.repeat)
    print(f"per datagram, {args.n} IMU datagrams ({len(plain[0])} bytes plain, {len(wrapped[0])} wrapped), "
          f"best of {args.repeat}:")
    print(f"  decode_input (reference)       {dec:7.2f} us   1.00x   {1e6 / dec:10.0f} /s")
    print(f"  unwrap (HMAC-SHA256/128, window){unw:6.2f} us   {unw / dec:4.2f}x   {1e6 / unw:10.0f} /s")
    print(f"  unwrap + decode_input          {both:7.2f} us   {both / dec:4.2f}x   {1e6 / both:10.0f} /s")
    print(f"  wrap (sender)                  {wr:7.2f} us   {wr / dec:4.2f}x   {1e6 / wr:10.0f} /s")
    print(f"  unwrap of a forgery (rejected) {fo:7.2f} us   {fo / dec:4.2f}x   {1e6 / fo:10.0f} /s")
    share = 100 * (both - dec) * 130 / 1e6
    print(f"authentication adds {both - dec:.2f} us per datagram: {share:.3f} % of one core at 130 /s "
          "(IMU 100 Hz + odometer 20 Hz + GNSS 10 Hz)")


if __name__ == "__main__":
    from sfa.cli import configure_numba_cache

    configure_numba_cache()  # keyed on the sources: never a stale compiled kernel after an edit
    main()
