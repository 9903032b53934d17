"""The command line's env overrides (`agents.cli.EnvOverrides`) read as the `envs.make` values a run
saves in config.json, so `eval`, `rollout` and `--resume` rebuild the same env; and the overflow
report that names them."""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import numpy as np

from envs.mjx_options import ENUMS, opt_defaults, opt_fields
from envs.mjx_warp import WarpBuffers
from envs.registry import options


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


def parse_bool(text: str) -> bool:
    if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
        raise ValueError(f"expected true or false, got {text!r}")
    return text.lower() in ("true", "1", "yes")


def parse_option(name: str, option: str, text: str) -> Any:
    """`--env-opt option=text` for env `name`, read as the option's default's type; `opt.FIELD` is
    one field of an MJX task's `opt` (`parse_opt_field`)."""
    valid = options(name)
    if option.startswith("opt.") and "opt" in valid:
        return parse_opt_field(option.removeprefix("opt."), text, f"env {name!r}")
    if option not in valid:
        raise ValueError(f"unknown option {option!r} for env {name!r}; valid options: {sorted(valid)}")
    default = valid[option]
    if option == "camera":  # a camera's index or name, whatever the task's default camera is
        return int(text) if text.lstrip("-").isdigit() else text
    if option in ("randomize", "opt") or dataclasses.is_dataclass(default):
        fix = {"randomize": "use --randomize FIELD:ELEMENT=LOW:HIGH",
               "opt": "set its fields one by one: --env-opt opt.iterations=4"}.get(option, "set its fields one by one")
        raise ValueError(f"option {option!r} of env {name!r} cannot be given as text; {fix}")
    try:
        if isinstance(default, bool):
            return parse_bool(text)
        if isinstance(default, (int, float)):
            return type(default)(text)
        if isinstance(default, tuple):  # an interval such as healthy_z_range, written LOW,HIGH (inf allowed)
            return tuple(float(part) for part in text.split(","))
        if default is None:  # no type to go by: a number if it reads as one
            for kind in (int, float):
                try:
                    return kind(text)
                except ValueError:
                    pass
        return text
    except ValueError as err:
        raise ValueError(f"bad value {text!r} for option {option!r} of env {name!r} "
                         f"(default {default!r}): {err}") from None


def parse_opt_field(field: str, text: str, task: str = "task") -> Any:
    """`--env-opt opt.FIELD=TEXT`: an enum by name, a vector as comma-separated numbers, else a number
    of the field's type (`envs.mjx_options` checks the value)."""
    if field not in opt_defaults():
        raise ValueError(f"{task}: unknown opt field {field!r}; valid fields (mujoco.MjOption): {list(opt_fields())}")
    default = opt_defaults()[field]
    try:
        if field in ENUMS:
            return int(text) if text.lstrip("-").isdigit() else text
        if isinstance(default, np.ndarray):
            return [float(part) for part in text.replace(",", " ").split()]
        return int(text) if isinstance(default, int) else float(text)
    except ValueError:
        shown = default.tolist() if isinstance(default, np.ndarray) else default
        raise ValueError(f"{task}: bad value {text!r} for opt.{field} (default {shown})") from None


def overflow_report(env, contact_steps: int, constraint_steps: int, steps: int, unit: str = "env-steps") -> str:
    """One log line: which of MuJoCo Warp's buffers ran out how often, and the `--env-opt` that fixes it."""
    buffers = getattr(env, "warp_buffers", None) or WarpBuffers(nconmax=0, njmax=0)  # wrappers pass it on
    parts = []
    if contact_steps:
        now = f"naconmax={buffers.naconmax} for the batch" if buffers.naconmax else f"nconmax={buffers.nconmax} per env"
        bigger = f"naconmax={2 * buffers.naconmax}" if buffers.naconmax else f"nconmax={2 * buffers.nconmax}"
        parts.append(f"its contact pool ({now}) on {contact_steps:,} of {steps:,} {unit}: raise it with "
                     f"--env-opt {bigger} (envs.make(..., {bigger}))")
    if constraint_steps:
        parts.append(f"its constraint rows (njmax={buffers.njmax} per env) on {constraint_steps:,} of {steps:,} "
                     f"{unit}: raise them with --env-opt njmax={2 * buffers.njmax} "
                     f"(envs.make(..., njmax={2 * buffers.njmax}))")
    return "MuJoCo Warp ran out of " + "; and of ".join(parts) + "."
