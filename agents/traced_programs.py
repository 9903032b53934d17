"""Traced programs kept across processes with `jax.export`, beside JAX's compilation cache (which skips
XLA's compile, not the tracing before it), in files named by a hash of everything that could change
them; switched with that cache (docs/results.md, "Startup"). Custom pytree nodes do not serialize, so
the exported function takes and returns flat lists of leaves, the trees pickled beside it.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import inspect
import json
import os
import pickle
import platform
import re
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np

from envs.mjx_warp import runs_warp

SUBDIR = "mjxsuite-export"  # inside JAX's cache directory, whose eviction only looks at its own files
_FORMAT = 1  # bump when the file layout below changes
_VERSIONED = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax", "numpy")
_directory: Path | None = None


def enable(directory: str | os.PathLike) -> Path:
    """Cache traced programs in `directory` (created when first written)."""
    global _directory
    _directory = Path(directory).expanduser()
    return _directory


def disable() -> None:
    global _directory
    _directory = None


def directory() -> Path | None:
    """Where traced programs are cached; None when the cache is off (the default)."""
    return _directory


@dataclass(frozen=True)
class CachedProgram:
    """A compiled program over flat leaves, called like the original function."""

    compiled: Callable  # the compiled program, taking one list of leaves
    out_tree: Any  # the original function's output structure
    hit: bool  # loaded from the cache (nothing traced but the call wrapper)

    def __call__(self, *args):
        return jax.tree.unflatten(self.out_tree, self.compiled(jax.tree.leaves(args)))


@dataclass(frozen=True)
class LoweredProgram:
    """A program traced and lowered, to compile (without Python's lock) on another thread while the
    caller traces the next (`agents.run`)."""

    lowered: Any  # jax.stages.Lowered
    compiler_options: dict | None
    out_tree: Any = None  # the original function's output structure; None: `lowered` takes the original arguments
    donated: int = 0  # leaves of the first argument donated (flat programs only)
    hit: bool = False  # loaded from the cache

    def compile(self) -> Callable:
        compiled = self.lowered.compile(self.compiler_options)
        if self.out_tree is None:
            return compiled
        donated = self.donated
        return CachedProgram(lambda flat: compiled(flat[:donated], flat[donated:]), self.out_tree, self.hit)


def cached_lower(fn: Callable, args: tuple, key_parts: Any, cache_dir: str | os.PathLike,
                 donate: bool = False, compiler_options: dict | None = None) -> LoweredProgram:
    """`fn` lowered for `args` (pytrees of arrays), its trace loaded from `cache_dir` or exported there.
    `key_parts` (JSON-able, else by `repr`) must describe every input of the trace that the shapes and
    `environment_fingerprint()` do not; `donate` donates the first argument's buffers."""
    leaves, in_tree = jax.tree.flatten(args)
    donated = len(jax.tree.leaves(args[0])) if donate and args else 0  # the first argument's leaves lead
    path = cache_file(cache_dir, key_parts, args)
    if path.is_file():
        try:
            exported, out_tree = _read(path, in_tree)
            return _lower(exported.call, leaves, donated, compiler_options, out_tree, hit=True)
        except Exception as err:  # corrupt, truncated, or from an incompatible jax: trace again
            warnings.warn(f"ignoring unreadable cached program {path} ({type(err).__name__}: {err}); tracing again")
    flat, found = _flat(fn, in_tree)
    try:
        blob = bytes(jax.export.export(jax.jit(flat))(leaves).serialize())
    except Exception as err:
        warnings.warn(f"cannot cache this program ({type(err).__name__}: {err}); compiling it without the cache")
        lowered = _split_jit(flat).lower(leaves[:donated], leaves[donated:])  # traces `flat`: fills `found`
        return LoweredProgram(lowered, compiler_options, found["out_tree"], donated)
    out_tree = found["out_tree"]
    _write(path, {"format": _FORMAT, "exported": blob, "in_tree": in_tree, "out_tree": out_tree})
    # Compile what a later hit will compile, so that its XLA compile is a persistent-cache hit.
    return _lower(jax.export.deserialize(bytearray(blob)).call, leaves, donated, compiler_options, out_tree, hit=False)


def lower_env_program(program: str, fn: Callable, args: tuple, env, env_name: str, env_options: dict | None,
                      extra: dict | None = None, donate: bool = False,
                      compiler_options: dict | None = None) -> LoweredProgram:
    """`fn` (a program that runs `env`) lowered for `args`: through this cache when it is on and the
    env can be fingerprinted, else by plain `jax.jit`. `extra`: whatever else the trace depends on."""
    key_parts = program_key_parts(program, env, env_name, env_options, extra) if _directory is not None else None
    if key_parts is None:  # cache off, or an env whose code cannot be hashed
        return LoweredProgram(jax.jit(fn, donate_argnums=0 if donate else ()).lower(*args), compiler_options)
    return cached_lower(fn, args, key_parts, _directory, donate=donate, compiler_options=compiler_options)


def program_key_parts(program: str, env, env_name: str, env_options: dict | None,
                      extra: dict | None = None) -> dict | None:
    """`lower_env_program`'s key, less what `cache_file` adds; None when the env cannot be
    fingerprinted, or runs MuJoCo Warp, whose FFI calls `jax.export` refuses (after a whole trace)."""
    fingerprint = None if runs_warp(env) else env_fingerprint(env)
    return None if fingerprint is None else {"program": program, "env_name": env_name, "env_options": env_options or {},
                                             "env": fingerprint, **(extra or {})}


def cache_file(cache_dir: str | os.PathLike, key_parts: Any, args: tuple) -> Path:
    """The file for `key_parts`, `args`' shapes and dtypes, and `environment_fingerprint()`."""
    leaves, in_tree = jax.tree.flatten(args)
    # Static data in the tree may print as addresses; `_read` compares the whole structure before use.
    signature = [_without_addresses(str(in_tree)), [str(jax.typeof(leaf)) for leaf in leaves]]
    return Path(cache_dir) / f"{_hash([key_parts, signature, environment_fingerprint()])}.pkl"


def _flat(fn: Callable, in_tree) -> tuple[Callable, dict]:
    """`fn` over one flat list of leaves, returning one; its output structure lands in the returned
    dict (under "out_tree") when it is traced."""
    found = {}

    def flat(leaves):
        out = fn(*jax.tree.unflatten(in_tree, leaves))
        out_leaves, found["out_tree"] = jax.tree.flatten(out)
        return out_leaves

    return flat, found


def _split_jit(flat_fn: Callable):
    """`flat_fn` (over one list of leaves) jitted as (head, tail) with the head donated."""
    return jax.jit(lambda head, tail: flat_fn([*head, *tail]), donate_argnums=0)


def _lower(flat_fn: Callable, leaves: list, donated: int, compiler_options: dict | None, out_tree,
           hit: bool) -> LoweredProgram:
    lowered = _split_jit(flat_fn).lower(leaves[:donated], leaves[donated:])
    return LoweredProgram(lowered, compiler_options, out_tree, donated, hit)


def _read(path: Path, in_tree) -> tuple[Any, Any]:
    with open(path, "rb") as f:
        entry = pickle.load(f)
    if entry["format"] != _FORMAT or entry["in_tree"] != in_tree:
        raise ValueError("written for other arguments or by another version of this module")
    exported = jax.export.deserialize(bytearray(entry["exported"]))
    if entry["out_tree"].num_leaves != len(exported.out_avals):
        raise ValueError("output structure does not match the program")
    return exported, entry["out_tree"]


def _write(path: Path, entry: dict) -> None:
    """Write atomically, so a concurrent run reads whole files only; a failure only warns."""
    temporary = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=path.stem, suffix=".tmp", delete=False) as f:
            temporary = f.name
            pickle.dump(entry, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(temporary, path)
    except OSError as err:
        warnings.warn(f"cannot write the traced-program cache {path}: {err}")
        if temporary is not None and os.path.exists(temporary):
            os.remove(temporary)


def _without_addresses(text: str) -> str:
    """`text` without the " at 0x..." of default reprs, which change from process to process."""
    return re.sub(r" at 0x[0-9a-fA-F]+", "", text)


def _hash(parts: Any) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=repr).encode()).hexdigest()[:32]


# ---- what else could change a traced program ----------------------------------
def environment_fingerprint() -> dict:
    """Versions, device, JAX's configuration and the suite's own source and models."""
    import envs
    from envs.assets import ASSET_DIRS

    device = jax.devices()[0]
    packages = [Path(envs.__file__).parent, Path(__file__).parent]
    sources = [p for package in packages for p in sorted(package.rglob("*.py"))]
    models = [p for d in ASSET_DIRS if d.is_dir() for p in sorted(d.glob("*.xml"))]
    return {
        "versions": {name: _version(name) for name in _VERSIONED},
        "python": platform.python_version(),
        "device": [jax.default_backend(), device.device_kind, device.client.platform_version, jax.device_count()],
        "jax_config": {name: repr(value) for name, value in sorted(jax.config.values.items())},
        "sources": files_hash(sources + models),
    }


def env_fingerprint(env) -> dict | None:
    """What an env adds to the key: its description, its classes' source and its MuJoCo model, if any.
    None when a class has no source file (e.g. defined at a prompt): its program must not be cached."""
    task = env.unwrapped
    sources = set()
    for cls in type(task).__mro__[:-1]:  # `object` last
        try:
            source = inspect.getsourcefile(cls)
        except (TypeError, OSError):  # a built-in class, or one without a file
            return None
        if source is None or not Path(source).is_file():
            return None
        sources.add(Path(source))
    parts = {
        "repr": _without_addresses(repr(env)),
        "class": f"{type(task).__module__}.{type(task).__qualname__}",
        "sources": files_hash(sorted(sources)),
        "episode_length": getattr(env, "episode_length", None),
    }
    model = getattr(task, "mj_model", None)
    if model is not None:
        import mujoco

        saved = np.empty(mujoco.mj_sizeModel(model), np.uint8)
        mujoco.mj_saveModel(model, None, saved)
        parts["mj_model"] = hashlib.sha256(saved.tobytes()).hexdigest()
    return parts


def files_hash(paths: list[Path]) -> str:
    digest = hashlib.sha256()
    for path in paths:
        digest.update(str(path).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None
