"""The command line's env overrides: `--env-opt KEY=VALUE`, `--impl`, `--randomize`, `--randomize-per`.

They become the `envs.make` overrides a run saves in config.json (`env_options`; the
`--env-opt opt.FIELD=VALUE` pairs as one `opt` mapping), so
`eval`, `rollout` and `--resume` rebuild the same env. `--randomize FIELD:ELEMENT=RANGE`
takes `LOW:HIGH` (a uniform range), `xLOW:HIGH` (a scale of the compiled value) or
`VALUE` (a fixed value); see `envs.randomize`.
"""

from __future__ import annotations

import argparse

from envs.randomize import PER
from envs.registry import options, parse_option


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The env-override options, on a train, eval or rollout parser."""
    parser.add_argument("--env-opt", dest="env_opts", action="append", default=[], metavar="KEY=VALUE",
                        help="an envs.make override, e.g. integrator=semi_implicit or episode_length=200 "
                             "(envs.options(NAME) lists them); an MJX task's MuJoCo solver option as "
                             "opt.FIELD=VALUE (opt.iterations=4, opt.solver=CG), MuJoCo Warp's buffers as "
                             "nconmax=N, naconmax=N, njmax=N; repeatable")
    parser.add_argument("--impl", choices=["jax", "warp"],
                        help="MJX implementation of an MJX task: jax (default) or warp (MuJoCo Warp, NVIDIA GPU, "
                             "pip install 'mjxsuite[warp]')")
    parser.add_argument("--randomize", action="append", default=[], metavar="FIELD:ELEMENT=RANGE",
                        help="draw an mjx.Model value per env: body_mass:pole=0.05:0.2 (uniform), "
                             "body_mass:pole=x0.8:1.2 (scale of the compiled value), dof_damping:slider=0.05 "
                             "(fixed); repeatable (docs/randomization.md)")
    parser.add_argument("--randomize-per", choices=PER,
                        help="draw again at every episode (default) or once per env")


def given(args: argparse.Namespace) -> bool:
    return bool(args.env_opts or args.impl or args.randomize or args.randomize_per)


def from_args(env_name: str, args: argparse.Namespace) -> dict:
    """The overrides the options give, as `envs.make` keywords (JSON-ready: ranges are lists)."""
    overrides = {}
    for pair in args.env_opts:
        key, sep, text = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--env-opt {pair!r}: expected KEY=VALUE, e.g. --env-opt episode_length=200")
        value = parse_option(env_name, key, text)
        if key.startswith("opt."):  # opt.FIELD=VALUE pairs make one `opt` mapping
            overrides.setdefault("opt", {})[key.removeprefix("opt.")] = value
        else:
            overrides[key] = value
    if args.impl:
        overrides["impl"] = parse_option(env_name, "impl", args.impl)
    if (args.randomize or args.randomize_per) and "randomize" not in options(env_name):
        raise ValueError(f"--randomize varies the model of an MJX task; {env_name!r} has none (analytic "
                         "envs take their physics constants as --env-opt, e.g. masspole=0.2)")
    if args.randomize:
        overrides["randomize"] = dict(parse_randomize(entry) for entry in args.randomize)
    if args.randomize_per:
        overrides["randomize_per"] = args.randomize_per
    return overrides


def merged(saved: dict, given: dict) -> dict:
    """A saved run's env options with those given now on top; `opt` mappings merge field by field."""
    options = {**saved, **given}
    if isinstance(saved.get("opt"), dict) and isinstance(given.get("opt"), dict):
        options["opt"] = {**saved["opt"], **given["opt"]}
    return options


def parse_randomize(entry: str) -> tuple[str, list | float]:
    """`FIELD:ELEMENT=LOW:HIGH`, `=xLOW:HIGH` or `=VALUE` as a (name, range) pair."""
    name, sep, text = entry.partition("=")
    try:
        if not sep:
            raise ValueError("no '='")
        scale = text.startswith("x")
        bounds = [float(b) for b in text.removeprefix("x").split(":")]
        if len(bounds) == 1 and not scale:
            return name, bounds[0]
        if len(bounds) != 2:
            raise ValueError("expected LOW:HIGH")
    except ValueError as err:
        raise ValueError(f"--randomize {entry!r}: {err}; write FIELD:ELEMENT=LOW:HIGH (uniform), "
                         "FIELD:ELEMENT=xLOW:HIGH (scale) or FIELD:ELEMENT=VALUE, "
                         "e.g. body_mass:pole=0.05:0.2") from None
    return name, (["x", *bounds] if scale else bounds)
