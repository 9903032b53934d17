"""Saving and loading training runs: the full train state (to resume) and the best parameters (to act)."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import serialization

from agents.dqn import DQNConfig

CONFIG_FILE = "config.json"
STATE_FILE = "train_state.msgpack"
POLICY_FILE = "best_params.msgpack"
PROGRESS_FILE = "progress.json"


def check_writable(out_dir: str | os.PathLike) -> Path:
    """Create `out_dir` and prove we can write there, before any compile or training starts."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output path {out} exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write_test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as err:
        raise ValueError(f"cannot write to output directory {out}: {err.strerror or err}") from err
    return out


def _atomic_write(path: Path, data: bytes) -> None:
    """Write then rename, so an interrupted save never leaves a truncated file behind."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def save_config(out_dir: Path, env: str, seeds: int, config: DQNConfig, env_options: dict | None = None) -> None:
    record = {"env": env, "seeds": seeds, "env_options": env_options or {}, "config": dataclasses.asdict(config)}
    _atomic_write(out_dir / CONFIG_FILE, json.dumps(record, indent=2).encode())


def load_config(out_dir: str | os.PathLike) -> tuple[str, int, DQNConfig, dict]:
    path = Path(out_dir) / CONFIG_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: is {out_dir} a directory written by `mjxsuite train --out`?")
    record = json.loads(path.read_text())
    fields = record["config"]
    fields["hidden"] = tuple(fields["hidden"])
    return record["env"], record["seeds"], DQNConfig(**fields), record.get("env_options", {})


def _to_bytes(tree: Any) -> bytes:
    """Any pytree (an `mjx.Data` env state included) as msgpack of its leaves, in order."""
    return serialization.msgpack_serialize({str(i): np.asarray(x) for i, x in enumerate(jax.tree.leaves(tree))})


def _from_bytes(template: Any, data: bytes) -> Any:
    """The inverse of `_to_bytes`, shaped like `template` (arrays or ShapeDtypeStructs)."""
    leaves = serialization.msgpack_restore(data)
    expected = jax.tree.leaves(template)
    if len(leaves) != len(expected) or any(
        np.shape(leaves[str(i)]) != tuple(t.shape) for i, t in enumerate(expected)
    ):
        raise ValueError("checkpoint does not match this config and env (different network, buffer or env, "
                         "or written by an older mjxsuite?)")
    return jax.tree.unflatten(jax.tree.structure(template), [leaves[str(i)] for i in range(len(expected))])


def save_state(out_dir: Path, train_state: Any, chunks_done: int) -> None:
    """The whole (seed-batched) train state, buffer included, so a resumed run continues exactly."""
    _atomic_write(out_dir / STATE_FILE, _to_bytes(train_state))
    _atomic_write(out_dir / POLICY_FILE, _to_bytes(train_state.best_params))
    progress = {"chunks_done": chunks_done, "best_return": [float(r) for r in train_state.best_return]}
    _atomic_write(out_dir / PROGRESS_FILE, json.dumps(progress).encode())


def load_state(out_dir: str | os.PathLike, template: Any) -> tuple[Any, int]:
    out = Path(out_dir)
    state = _from_bytes(template, (out / STATE_FILE).read_bytes())
    chunks_done = json.loads((out / PROGRESS_FILE).read_text())["chunks_done"]
    return state, chunks_done


def load_best_returns(out_dir: str | os.PathLike) -> list[float]:
    return json.loads((Path(out_dir) / PROGRESS_FILE).read_text())["best_return"]


def load_best_params(out_dir: str | os.PathLike, template: Any) -> Any:
    path = Path(out_dir) / POLICY_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: no checkpoint in {out_dir}")
    return _from_bytes(template, path.read_bytes())
