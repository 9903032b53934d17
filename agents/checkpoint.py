"""Saving and loading training runs: the full train state (to resume) and the best parameters (to act).

A run directory (`mjxsuite train --out DIR`) holds config.json, train_state.ckpt (all an exact resume
needs), best_params.ckpt, metrics.jsonl and progress.json; a run of several processes adds
processes.json, naming each process's directory under processes/. Every file is written atomically.
A .ckpt file is a JSON header under its own CRC32, describing each array, followed by the arrays'
raw bytes, so a damaged or foreign file is refused by name (docs/reliability.md).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import struct
import sys
import threading
import time
import zlib
from pathlib import Path
from typing import Any, BinaryIO, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from agents import registry

CONFIG_FILE = "config.json"
STATE_FILE = "train_state.ckpt"
POLICY_FILE = "best_params.ckpt"
OLDER_FILES = {STATE_FILE: "train_state.msgpack", POLICY_FILE: "best_params.msgpack"}  # format 2's names
PROGRESS_FILE = "progress.json"
METRICS_FILE = "metrics.jsonl"
PROCESSES_FILE = "processes.json"
PROCESSES_DIR = "processes"  # where a run of several processes keeps each one's run directory
FORMAT, VERSION = "mjxsuite-checkpoint", 3  # bump VERSION when the layout of the .ckpt files changes
MAGIC = b"MJXSCKPT"
PREFIX = struct.Struct("<8sQI")  # MAGIC, the header's length, its CRC32
ALIGN = 64  # every array starts at a multiple of this many bytes after the header


class CheckpointError(Exception):
    """A run directory's file cannot be written or read: a runtime failure (the CLI exits 1)."""


class SavedRun(NamedTuple):
    """What config.json records: enough to rebuild the run (`mjxsuite train --out DIR --resume`)."""

    env: str
    seeds: int
    config: Any  # the agent's config: DQNConfig, PPOConfig or SACConfig
    env_options: dict
    seed: int
    sweep: dict | None = None  # `mjxsuite sweep`'s grid ({field: [values]}); the run holds configs x seeds agents
    agent: str = "dqn"
    judge_every: int | None = None  # chunks between greedy judges (`run_steps.judge_every`); None: not yet resolved
    # (start, stop): the seeds this directory trains, of a run of several processes; None: every seed
    seed_slice: tuple[int, int] | None = None

    @property
    def trained_seeds(self) -> int:
        """The seeds this directory trains (its train state's leading axis, per config)."""
        return self.seeds if self.seed_slice is None else self.seed_slice[1] - self.seed_slice[0]


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


def atomic_write(path: Path, data: bytes | Callable[[BinaryIO], None]) -> None:
    """Write `data` (or what `data(file)` writes) to a temporary file, fsync it and rename it over `path`."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data) if isinstance(data, bytes) else data(f)
            f.flush()
            os.fsync(f.fileno())  # the rename must not reach the disk before the data (power loss)
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise CheckpointError(f"could not write {path}: {err.strerror or err}. Any earlier {path.name} is "
                              f"intact; free some space (or fix {path.parent}) and continue the run with "
                              f"`mjxsuite train --out {path.parent} --resume`") from err


def start_run(out_dir: Path, run: SavedRun) -> None:
    """Write config.json for a new run, first removing an earlier run's checkpoint (never resumed as this one)."""
    if (out_dir / PROCESSES_FILE).is_file():  # a run of several processes replaced: their directories too
        shutil.rmtree(out_dir / PROCESSES_DIR, ignore_errors=True)
    for stale in (STATE_FILE, POLICY_FILE, *OLDER_FILES.values(), PROGRESS_FILE, "eval.json", PROCESSES_FILE):
        (out_dir / stale).unlink(missing_ok=True)
    record = {"agent": run.agent, "env": run.env, "seeds": run.seeds, "seed": run.seed,
              "env_options": run.env_options or {}, "config": dataclasses.asdict(run.config)}
    optional = {"sweep": run.sweep or None, "judge_every": run.judge_every,
                "seed_slice": None if run.seed_slice is None else list(run.seed_slice)}
    record.update({name: value for name, value in optional.items() if value is not None})
    atomic_write(out_dir / CONFIG_FILE, json.dumps(record, indent=2).encode())


def load_config(out_dir: str | os.PathLike) -> SavedRun:
    path = Path(out_dir) / CONFIG_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: is {out_dir} a directory written by `mjxsuite train --out`?")
    try:
        record = json.loads(path.read_text())
        agent = record.get("agent", "dqn")  # runs from before PPO and SAC existed are DQN's
        config = config_from_record(registry.config_class(agent), record["config"])
        seed_slice = tuple(record["seed_slice"]) if record.get("seed_slice") is not None else None
        return SavedRun(record["env"], record["seeds"], config, record.get("env_options", {}),
                        record.get("seed", 0), record.get("sweep"), agent, record.get("judge_every"), seed_slice)
    except (ValueError, KeyError, TypeError) as err:  # json's errors are ValueErrors
        raise CheckpointError(f"{path} is damaged or was written by another mjxsuite version "
                              f"({type(err).__name__}: {err}); restore it or start a new run") from err


def saved_env(out_dir: str | os.PathLike, given: dict | None = None) -> tuple[str, Any, dict]:
    """`(env_name, env, env_options)` of a run directory, the options `given` on top of the saved ones;
    impl="warp" falls back to impl="jax" where Warp cannot run (docs/reliability.md, "Run directories are portable")."""
    import envs
    from envs.mjx_warp import BUFFER_OPTIONS, WarpUnavailable

    from agents.env_options import merged

    saved = load_config(out_dir)
    def without_warp_buffers(options: dict) -> dict:  # MuJoCo Warp's sizes mean nothing to impl="jax"
        return {k: v for k, v in options.items() if k not in BUFFER_OPTIONS}

    options = merged(saved.env_options, given or {})
    if options.get("impl") != "warp":  # e.g. a warp run judged with --impl jax
        options = without_warp_buffers(options)
    try:
        return saved.env, envs.make(saved.env, **options), options
    except WarpUnavailable:
        if options.get("impl") != "warp" or (given or {}).get("impl") == "warp":
            raise
    options = {**without_warp_buffers(options), "impl": "jax"}
    print(f"note: {out_dir} was trained with impl='warp', which this machine cannot run (no CUDA GPU or no "
          "warp-lang); its physics runs with impl='jax' here", file=sys.stderr)
    return saved.env, envs.make(saved.env, **options), options


def has_state(out_dir: Path) -> bool:
    """Whether the run directory holds a train state (an older mjxsuite's too: `load_state` refuses it by name)."""
    return any((Path(out_dir) / name).is_file() for name in (STATE_FILE, OLDER_FILES[STATE_FILE]))


def chunks_saved(out_dir: Path) -> int:
    """Chunks the run directory's checkpoint holds (0: none yet)."""
    if not (Path(out_dir) / STATE_FILE).is_file():
        return 0
    try:
        return int(json.loads((Path(out_dir) / PROGRESS_FILE).read_text())["chunks_done"])
    except (OSError, ValueError, KeyError):
        return 0


def describe(out_dir: Path) -> str:
    """A run directory's run in a few words, for messages: "dqn on cartpole, 3 of 50 chunks saved"."""
    try:
        saved = load_config(out_dir)
    except (CheckpointError, FileNotFoundError):
        return "an unreadable config.json"
    progress = Path(out_dir) / PROGRESS_FILE
    try:
        done = json.loads(progress.read_text()).get("chunks_done", 0) if progress.is_file() else 0
    except (ValueError, OSError):
        done = "?"
    finished = " finished," if (Path(out_dir) / "eval.json").is_file() else ""
    return f"{saved.agent} on {saved.env},{finished} {done} chunks or evaluations saved"


# Config fields that a later version removed, each with why a run saved with it reads the same without it.
RETIRED_FIELDS = {"image_seeds": "it chose how a GPU batched the seeds of camera images, not what they compute"}


def config_from_record(config_class: type, fields: dict) -> Any:
    """A config dataclass from its JSON record (JSON's lists back to the tuples of layer widths), the
    fields in `RETIRED_FIELDS` left out."""
    tuples = {f.name for f in dataclasses.fields(config_class) if "tuple" in str(f.type)}
    return config_class(**{name: tuple(value) if name in tuples else value for name, value in fields.items()
                           if name not in RETIRED_FIELDS})


def _write_arrays(path: Path, kind: str, tree: Any, meta: dict) -> None:
    """Any pytree's leaves as raw bytes after a header that describes them and carries `meta`; atomically."""
    leaves = [np.asarray(x, order="C") for x in jax.tree.leaves(tree)]  # (ascontiguousarray makes scalars 1-D)
    specs, offset = [], 0
    for x in leaves:
        specs.append({"dtype": x.dtype.name, "shape": list(x.shape), "offset": offset, "nbytes": x.nbytes,
                      "crc32": zlib.crc32(_bytes_of(x))})
        offset += -(-x.nbytes // ALIGN) * ALIGN
    header = json.dumps({"format": FORMAT, "version": VERSION, "kind": kind, "meta": meta, "leaves": specs,
                         "data_bytes": offset}).encode()
    header += b" " * (-(PREFIX.size + len(header)) % ALIGN)  # the arrays start aligned

    def write(f: BinaryIO) -> None:
        f.write(PREFIX.pack(MAGIC, len(header), zlib.crc32(header)) + header)
        for x, spec in zip(leaves, specs):
            f.write(_bytes_of(x))
            f.write(b"\0" * (-spec["nbytes"] % ALIGN))

    atomic_write(path, write)


def _bytes_of(x: np.ndarray) -> memoryview:
    return memoryview(x.reshape(-1).view(np.uint8)) if x.size else memoryview(b"")


def _read(path: Path, kind: str, env: str | None, fix: str) -> tuple[dict, bytearray]:
    """The checked header and array bytes of a `_write_arrays` file (for `env`; None: any), else a CheckpointError."""
    if not path.is_file():
        older = path.with_name(OLDER_FILES.get(path.name, path.name))
        if older != path and older.is_file():
            raise CheckpointError(f"{older} was written by an older mjxsuite (checkpoint format 2, before "
                                  f"{path.name}); {fix}")
        raise FileNotFoundError(f"{path} not found: no checkpoint in {path.parent}")

    def damaged(what: str) -> CheckpointError:
        return CheckpointError(f"{path} {what}; {fix}")

    with open(path, "rb") as f:
        prefix = f.read(PREFIX.size)
        if prefix[:len(MAGIC)] != MAGIC:
            older = prefix[:1] and (0x80 <= prefix[0] <= 0x8F or prefix[0] in (0xDE, 0xDF))  # a msgpack map
            if len(prefix) < len(MAGIC) and MAGIC.startswith(prefix):
                raise damaged("is truncated")
            raise damaged("was written by an older mjxsuite (checkpoint format 1 or 2)" if older
                          else "is not an mjxsuite checkpoint")
        if len(prefix) < PREFIX.size:
            raise damaged("is truncated")
        _, header_size, header_crc = PREFIX.unpack(prefix)
        header_bytes = f.read(header_size)
        if len(header_bytes) < header_size:
            raise damaged("is truncated")
        if zlib.crc32(header_bytes) != header_crc:
            raise damaged("is corrupted (its header fails its CRC32 check)")
        header = json.loads(header_bytes)
        if header.get("format") != FORMAT or header.get("version") != VERSION or header.get("kind") != kind:
            raise damaged(f"was written by another mjxsuite version (format {header.get('version')}, "
                          f"{header.get('kind')}; this one reads format {VERSION}, {kind})")
        data = bytearray(header["data_bytes"])
        if f.readinto(data) < len(data):
            raise damaged("is truncated")
    for spec in header["leaves"]:
        if zlib.crc32(memoryview(data)[spec["offset"]:spec["offset"] + spec["nbytes"]]) != spec["crc32"]:
            raise damaged("is corrupted (its arrays fail their CRC32 check)")
    if env is not None and header["meta"].get("env") != env:
        raise damaged(f"was written for env {header['meta'].get('env')!r}, not {env!r}")
    return header, data


def _unflatten(path: Path, record: tuple[dict, bytearray], template: Any, fix: str) -> Any:
    """The arrays of `record` (what `_read` returned), shaped like `template` (arrays or ShapeDtypeStructs)."""
    header, data = record
    specs, expected = header["leaves"], jax.tree.leaves(template)
    if len(specs) != len(expected) or any(tuple(spec["shape"]) != tuple(t.shape) for spec, t in zip(specs, expected)):
        raise CheckpointError(f"{path} does not match its {CONFIG_FILE} (another network, buffer, env or number "
                              f"of seeds); {fix}")
    leaves = [np.frombuffer(data, jnp.dtype(spec["dtype"]), int(np.prod(spec["shape"])), spec["offset"])
              .reshape(spec["shape"]) for spec in specs]
    return jax.tree.unflatten(jax.tree.structure(template), leaves)


def read_leaves(path: str | os.PathLike, kind: str) -> tuple[dict, list[np.ndarray]]:
    """A .ckpt file's meta and its arrays in order, checked, for tools that compare runs."""
    path = Path(path)
    header, data = _read(path, kind, None, POLICY_FIX)
    shapes = [jax.ShapeDtypeStruct(tuple(spec["shape"]), jnp.dtype(spec["dtype"])) for spec in header["leaves"]]
    return header["meta"], _unflatten(path, (header, data), shapes, POLICY_FIX)


RESUME_FIX = "it cannot be resumed: start the run again without --resume, or in a new --out"
POLICY_FIX = "train the agent again, or use another run directory"


def without_replay(train_state: Any) -> Any:
    """`train_state` (or a template) without its replay `buffer`: what a finished run's checkpoint holds."""
    return train_state.replace(buffer=None) if hasattr(train_state, "buffer") else train_state


def save_state(out_dir: Path, env: str, train_state: Any, chunks_done: int, finished: bool = False,
               clock: dict | None = None) -> None:
    """The whole train state (a `finished` run's `without_replay`), with its own chunk count, and the best
    parameters. `clock`: the run's seconds so far (`saved_clock`), in progress.json too (read without the state)."""
    best_return = save_policy(out_dir, env, train_state.best_params, train_state.best_return)
    if finished:
        train_state = without_replay(train_state)
    _write_arrays(out_dir / STATE_FILE, "train_state", train_state,
                  {"env": env, "chunks_done": chunks_done, "replay_left_out": finished, "clock": clock or {}})
    atomic_write(out_dir / PROGRESS_FILE, json.dumps({"chunks_done": chunks_done, "best_return": best_return,
                                                       "clock": clock or {}}).encode())


def save_policy(out_dir: Path, env: str, best_params: Any, best_return: Any) -> list[float]:
    """best_params.ckpt alone (what `load_best_params` and a judge read), with its agents' best returns."""
    best_return = [float(r) for r in np.asarray(best_return)]
    _write_arrays(out_dir / POLICY_FILE, "best_params", best_params, {"env": env, "best_return": best_return})
    return best_return


class BackgroundSaves:
    """`save_state` on a non-daemon thread of its own, one save at a time: `save` and `wait` wait for the
    previous one, raising its error. `written_s`: the last write's seconds."""

    def __init__(self):
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self.written_s = 0.0

    def save(self, out_dir: Path, env: str, host_state: Any, chunks_done: int, finished: bool = False,
             clock: dict | None = None) -> None:
        """Write `host_state` (numpy arrays, or a function that makes them on the writing thread)."""
        self.wait()

        def write():
            try:
                start = time.perf_counter()
                save_state(out_dir, env, host_state() if callable(host_state) else host_state, chunks_done, finished,
                           clock)
                self.written_s = time.perf_counter() - start
            except BaseException as err:  # raised again by the next save or wait, on the run's thread
                self._error = err

        self._thread = threading.Thread(target=write, name="checkpoint-save")
        self._thread.start()

    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def wait(self) -> None:
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._error is not None:
            error, self._error = self._error, None
            raise error


def load_state(out_dir: str | os.PathLike, env: str, template: Any) -> tuple[Any, int]:
    """The saved train state, shaped like `template` (a finished run's `without_replay`), and its chunks done."""
    path = Path(out_dir) / STATE_FILE
    record = _read(path, "train_state", env, RESUME_FIX)
    meta = record[0]["meta"]
    if meta.get("replay_left_out"):
        template = without_replay(template)
    return _unflatten(path, record, template, RESUME_FIX), int(meta["chunks_done"])


def saved_clock(out_dir: str | os.PathLike) -> dict:
    """The run's clock at its checkpoint (`agents.run.RunResult`'s `wall_s`, ...; {}: none), for a --resume."""
    with open(Path(out_dir) / STATE_FILE, "rb") as f:
        _, header_size, _ = PREFIX.unpack(f.read(PREFIX.size))
        return json.loads(f.read(header_size))["meta"].get("clock") or {}


def check_saved(out_dir: str | os.PathLike, env: str) -> None:
    """Read both checkpoint files through, as a resume and `eval` would (CheckpointError naming a bad one)."""
    _read(Path(out_dir) / STATE_FILE, "train_state", env, RESUME_FIX)
    _read(Path(out_dir) / POLICY_FILE, "best_params", env, POLICY_FIX)


def process_dirs(out_dir: str | os.PathLike) -> list[tuple[Path, tuple[int, int]]] | None:
    """Each process's run directory and seeds (start, stop), in seed order; None for a run of one process."""
    path = Path(out_dir) / PROCESSES_FILE
    if not path.is_file():
        return None
    try:
        return [(Path(out_dir) / entry["directory"], tuple(entry["seed_slice"]))
                for entry in json.loads(path.read_text())["processes"]]
    except (ValueError, KeyError, TypeError) as err:
        raise CheckpointError(f"{path} is damaged ({type(err).__name__}: {err}); restore it or start a new run") from err


def load_best_returns(out_dir: str | os.PathLike) -> list[float]:
    out = Path(out_dir)
    parts = process_dirs(out)
    if parts is not None:
        return [value for directory, _ in parts for value in load_best_returns(directory)]
    return _read(out / POLICY_FILE, "best_params", load_config(out).env, POLICY_FIX)[0]["meta"]["best_return"]


def best_seed(out_dir: str | os.PathLike) -> int:
    """The seed a run's policy acts with by default: eval.json's `best_seed`, else the best so far."""
    finished = Path(out_dir) / "eval.json"
    if finished.is_file():
        try:
            return int(json.loads(finished.read_text())["best_seed"])
        except (ValueError, KeyError, TypeError):  # an eval.json of an older mjxsuite
            pass
    return int(np.argmax(load_best_returns(out_dir)))


def load_best_params(out_dir: str | os.PathLike, template: Any) -> Any:
    """Every seed's best parameters, shaped like `template` (leading seed axis), across processes."""
    out = Path(out_dir)
    parts = process_dirs(out)
    if parts is not None:
        loaded = [load_best_params(directory, jax.tree.map(lambda t: jax.ShapeDtypeStruct((stop - start, *t.shape[1:]),
                                                                                         t.dtype), template))
                  for directory, (start, stop) in parts]
        return jax.tree.map(lambda *slices: np.concatenate(slices), *loaded)
    path = out / POLICY_FILE
    return _unflatten(path, _read(path, "best_params", load_config(out).env, POLICY_FIX), template, POLICY_FIX)


def keep_metrics(out_dir: Path, chunks_done: int) -> None:
    """Keep the metrics of the chunks the resumed train state has done (the resumed run writes the rest)."""
    path = out_dir / METRICS_FILE
    lines = path.read_text().splitlines(keepends=True) if path.is_file() else []
    atomic_write(path, "".join(lines[:chunks_done]).encode())


def check_resumable(out_dir: Path, run: SavedRun) -> None:
    """Refuse to resume `out_dir` as a run other than the one it holds (ValueError: a usage error)."""
    saved = load_config(out_dir)
    asked = run._replace(env_options=json.loads(json.dumps(run.env_options or {})),  # as JSON stores them
                         sweep=json.loads(json.dumps(run.sweep)) if run.sweep else None)
    if saved.judge_every is None:  # saved before its cadence was resolved (a run of several processes, an older
        asked = asked._replace(judge_every=None)  # mjxsuite): the config's own cadence, `run_steps.judge_every`
    differ = [f"{name} {getattr(saved, name)!r} (given {getattr(asked, name)!r})"
              for name in SavedRun._fields if name != "config" and getattr(saved, name) != getattr(asked, name)]
    if saved.agent == asked.agent:
        saved_config, asked_config = dataclasses.asdict(saved.config), dataclasses.asdict(asked.config)
        differ += [f"config.{name} {value!r} (given {asked_config[name]!r})"
                   for name, value in saved_config.items() if value != asked_config[name]]
    if differ:
        raise ValueError(f"--resume continues the run saved in {out_dir}, which has {'; '.join(differ)}; "
                         "drop those options (they come from the directory) or start a new --out")
