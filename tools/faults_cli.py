"""``sfa faults``: the deterministic UDP fault proxy and reliability campaigns.

    sfa faults proxy --listen 127.0.0.1:P --forward 127.0.0.1:Q --loss 0.2 --reorder 0.05 \
        --duplicate 0.01 --seed 1
    sfa faults proxy --listen 127.0.0.1:P --forward 127.0.0.1:Q --profile FILE.toml [--table input_link]
    sfa faults campaign tools/faults/campaigns/quick.toml [--jobs N] [--out DIR] [--mode replay|live]

The proxy's options are the fields of ``tools.faults.config.Impairments`` (``-`` for ``_``); given
options override the profile's. See docs/reliability.md.
"""

from __future__ import annotations

import argparse

#: proxy options: (field, type, help); the field names of Impairments
_PROXY_OPTIONS = (
    ("loss", float, "Bernoulli loss probability per datagram"),
    ("ge_p_good_bad", float, "Gilbert-Elliott: P(GOOD -> BAD) per datagram (burst loss; 0: off)"),
    ("ge_p_bad_good", float, "Gilbert-Elliott: P(BAD -> GOOD) per datagram"),
    ("ge_loss_good", float, "Gilbert-Elliott: loss probability in GOOD"),
    ("ge_loss_bad", float, "Gilbert-Elliott: loss probability in BAD"),
    ("duplicate", float, "probability a datagram is sent twice"),
    ("duplicate_gap_s", float, "delay of the copy [s]"),
    ("reorder", float, "probability a datagram is held behind the next one of the same sender"),
    ("reorder_max_s", float, "longest reorder hold [s]"),
    ("delay_s", float, "fixed delay [s]"),
    ("jitter_s", float, "uniform extra delay in [0, jitter] (order kept per sender) [s]"),
    ("bitflip", float, "probability of bit flips in a datagram"),
    ("bitflip_bits", int, "bits flipped per corrupted datagram"),
    ("truncate", float, "probability a datagram is cut short"),
    ("replay", float, "probability an earlier datagram of the same sender is re-sent"),
    ("forge_rate_hz", float, "forged INPUT datagrams per second"),
    ("forge_count", int, "most forged datagrams (0: no limit)"),
    ("forge_valid_fraction", float, "fraction of forged datagrams that are well-formed and in range"),
    ("forge_kind", str, "valid forgeries: random, ground_truth, stop or seq_jump (with --forge-on-stream)"),
    ("forge_seq_offset", int, "seq_jump: SEQ ahead of the real sender's newest datagram"),
    ("garbage_rate_hz", float, "random-byte datagrams per second (flood)"),
    ("garbage_max_bytes", int, "longest garbage datagram [bytes]"),
    ("inject_start_s", float, "injections start after this long [s]"),
    ("inject_end_s", float, "injections end after this long [s]"),
)


def _addr(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT")
    return host.strip("[]"), int(port)


def _window(text: str) -> tuple[float, float]:
    start, sep, dur = text.partition(":")
    try:
        a, b = float(start), float(dur)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected START:DURATION in seconds") from None
    if not sep or a < 0 or b <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected START:DURATION, START >= 0, DURATION > 0")
    return a, b


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="faults_command", metavar="SUBCOMMAND")
    p = sub.add_parser("proxy", help="deterministic UDP fault proxy (one link, both directions)")
    p.add_argument("--listen", type=_addr, required=True, metavar="HOST:PORT", help="where clients send")
    p.add_argument("--forward", type=_addr, required=True, metavar="HOST:PORT", help="where datagrams go")
    p.add_argument("--seed", type=int, default=0, help="seed of every random decision (default 0)")
    p.add_argument("--profile", help="TOML file with Impairments fields (options given here override it)")
    p.add_argument("--table", help="table of the profile file to use (e.g. input_link)")
    for name, typ, text in _PROXY_OPTIONS:
        p.add_argument(f"--{name.replace('_', '-')}", dest=name, type=typ, default=None, help=text)
    p.add_argument("--blackout", type=_window, action="append", default=None, metavar="START:DURATION",
                   help="nothing passes either way in this window, seconds from the first datagram "
                   "(repeatable)")
    p.add_argument("--forge-on-stream", action="store_true", default=None,
                   help="send forged datagrams from a real client's upstream socket")
    p.add_argument("--impair-replies", action="store_true", default=None,
                   help="apply loss, duplication and corruption to replies as well")
    p.add_argument("--auth-key-file", help="master key file (hex): forgeries posing as a module on an "
                   "authenticated stream are signed with that module's key (a compromised key)")
    p.add_argument("--duration", type=float, help="exit after this many seconds")
    p.add_argument("--idle-exit", type=float, help="exit after this many seconds without client datagrams")
    p.set_defaults(faults_run=_run_proxy)

    c = sub.add_parser("campaign", help="run a TOML matrix of fault scenarios and write the results tables")
    c.add_argument("file", help="campaign TOML (see tools/faults/campaigns/)")
    c.add_argument("--mode", choices=("replay", "live"), default="replay",
                   help="replay: scripted time in-process (default); live: real processes on loopback")
    c.add_argument("--jobs", type=int, help="scenarios run at once (default: the number of cores)")
    c.add_argument("--out", default="faults-out", help="output directory (default faults-out)")
    c.add_argument("--only", action="append", metavar="NAME", help="run only this scenario (repeatable)")
    c.add_argument("--executor", choices=("local", "dask"), default="local",
                   help="local process pool (default) or an existing Dask cluster")
    c.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address for --executor dask")
    c.set_defaults(faults_run=_run_campaign)


def run(args: argparse.Namespace) -> int:
    from tools.faults.errors import FaultConfigError

    handler = getattr(args, "faults_run", None)
    if handler is None:
        raise FaultConfigError("a subcommand is required: proxy or campaign (see sfa faults --help)")
    return handler(args)


def _run_proxy(args: argparse.Namespace) -> int:
    import asyncio
    import dataclasses

    from tools.faults.config import Impairments, load_profile
    from tools.faults.core import FaultCore
    from tools.faults.errors import FaultConfigError
    from tools.faults.proxy import UdpFaultProxy

    base = load_profile(args.profile, args.table) if args.profile else Impairments()
    changes = {name: getattr(args, name) for name, _, _ in _PROXY_OPTIONS if getattr(args, name) is not None}
    if args.blackout is not None:
        changes["blackouts"] = tuple(args.blackout)
    for flag in ("forge_on_stream", "impair_replies"):
        if getattr(args, flag):
            changes[flag] = True
    imp = dataclasses.replace(base, **changes).validate()
    for name in ("duration", "idle_exit"):
        value = getattr(args, name)
        if value is not None and value <= 0:
            raise FaultConfigError(f"--{name.replace('_', '-')} must be > 0")
    sign = None
    if args.auth_key_file:
        from listener.config import read_master_key
        from tools.faults.forge import module_signer

        sign = module_signer(read_master_key(args.auth_key_file))
    proxy = UdpFaultProxy(FaultCore(imp, args.seed, sign=sign), args.listen, args.forward)
    asyncio.run(proxy.run(duration_s=args.duration, idle_exit_s=args.idle_exit))
    return 0


def _run_campaign(args: argparse.Namespace) -> int:
    import sys

    from tools.faults.campaign import run_campaign
    from tools.faults.errors import FaultConfigError
    from tools.faults.spec import load_campaign

    if args.jobs is not None and args.jobs < 1:
        raise FaultConfigError(f"--jobs must be >= 1, got {args.jobs}")
    campaign = load_campaign(args.file)
    print(f"sfa faults campaign: {campaign.name}: {len(campaign.scenarios)} scenarios, mode {args.mode}, "
          f"out {args.out}", file=sys.stderr, flush=True)

    def progress(row):
        text = f"  {row['scenario']}: {row.get('verdict')} ({row.get('wall_s', '?')} s)"
        print(f"{text} {row.get('checks', '')} {row.get('notes', '')}".rstrip(), file=sys.stderr, flush=True)

    rows = run_campaign(campaign, args.mode, args.out, jobs=args.jobs, executor=args.executor,
                        scheduler=args.scheduler, only=args.only, progress=progress)
    bad = [r["scenario"] for r in rows if r.get("verdict") not in ("PASS", "SKIP")]
    print(f"results: {args.out}/results.md, .csv, .html; {len(rows) - len(bad)}/{len(rows)} PASS"
          + (f"; not passing: {', '.join(bad)}" if bad else ""), file=sys.stderr)
    return 0 if not bad else 1
