"""The `mjxsuite` command: `agents.cli`'s train, eval and rollout, plus `bench`.

This is the console script's entry point (`pyproject.toml`), the one place that joins
the library's command line with the benchmarks: `agents` never imports `benchmarks`.
`python -m agents.cli` runs the library's commands alone.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import envs
from agents import cli
from benchmarks.suite import DEFAULT_SECTIONS, SECTIONS


def add_parser(sub) -> None:
    bench = sub.add_parser("bench", help="benchmark env throughput (vs gymnax and MuJoCo Playground), DQN, logging",
                           description="Runs every benchmark figure of docs/results.md (see benchmarks/suite.py). "
                                       "Peers come from the bench extra; a missing one is recorded as skipped.")
    bench.add_argument("--quick", action="store_true", help="fewer batch sizes, repeats and DQN runs (minutes on a CPU)")
    bench.add_argument("--json", metavar="FILE", help="write the records (a JSON list) to FILE")
    bench.add_argument("--merge", action="store_true",
                       help="with --json: keep FILE's other records, replacing only those of the kinds this run wrote "
                            "(its meta record notes the sections re-run and when)")
    bench.add_argument("--sections", nargs="+", default=list(DEFAULT_SECTIONS), choices=SECTIONS,
                       help=f"what to run (default: {' '.join(DEFAULT_SECTIONS)})")
    bench.add_argument("--envs", nargs="*", default=["cartpole", "cartpole-mjx"], choices=envs.names(),
                       help="our envs in the env section (default: the two CartPoles; any registered env)")
    bench.add_argument("--batch", nargs="+", type=int, metavar="N", help="env batch sizes (default: by device)")
    bench.add_argument("--peers", nargs="*", default=["gymnax", "playground"], choices=["gymnax", "playground"],
                       help="peer libraries in the env section (none: ours only)")
    bench.add_argument("--repeats", type=int, help="timed runs per env figure (default 5, 3 with --quick)")
    bench.add_argument("--peer-dqn", metavar="FILE", help="a PureJaxRL-style dqn.py (its make_train) to run beside our "
                       "DQN in the dqn section (needs gymnax and flashbax); without it those rows are skipped")
    bench.add_argument("--plot", metavar="FILE.json", help="plot throughput against batch size from saved records")
    bench.add_argument("--out", default="docs/throughput.png", help="where --plot writes (default %(default)s)")
    bench.add_argument("--table", metavar="FILE.json", help="print markdown tables from saved records")


def cmd_bench(args, extra: list[str]) -> int:
    from benchmarks import suite

    if extra:
        raise cli.UsageError(f"bench: unexpected arguments {extra}")
    if args.table:
        print(suite.tables(suite.load_records(args.table)))
    if args.plot:
        print(f"wrote {suite.plot(suite.load_records(args.plot), args.out)}")
    if args.plot or args.table:
        return 0
    if args.json:  # fail before an hour of benchmarking, not after (and leave no empty file behind)
        target = Path(args.json)
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise cli.UsageError(f"bench: cannot write {target}: {err}")
        if target.is_dir() or not os.access(target if target.exists() else target.parent, os.W_OK):
            raise cli.UsageError(f"bench: cannot write {target}")
    records = suite.run_bench(args.quick, args.sections, batch=args.batch, ours=args.envs, peers=args.peers,
                              repeats=args.repeats, peer_dqn=args.peer_dqn)
    if args.json and args.merge and Path(args.json).is_file():
        records = suite.merge_records(suite.load_records(args.json), records)
    if args.json:
        Path(args.json).write_text(json.dumps(records, indent=2))
        print(f"wrote {len(records)} records to {args.json}")
    return 0


COMMANDS = {"bench": cli.Command(add_parser, cmd_bench)}


def build_parser():
    """The whole `mjxsuite` argument parser (the docs test checks every documented command line with it)."""
    return cli.build_parser(COMMANDS)


def main(argv: list[str] | None = None) -> int:
    return cli.main(argv, COMMANDS)


if __name__ == "__main__":
    sys.exit(main())
