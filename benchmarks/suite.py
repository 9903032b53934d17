"""`mjxsuite bench`: every figure of docs/results.md, from one command.

Sections (all by default; pick with `--sections`):

- `env`: env-steps/s of `cartpole` and `cartpole-mjx` at batch sizes from 1 up, beside
  gymnax `CartPole-v1` and MuJoCo Playground `CartpoleBalance` (impl="jax"), and the
  ratios (`benchmarks.env_throughput`, `benchmarks.peers`);
- `dqn`: DQN env-steps/s and updates/s with 1 and 16 vmapped seeds, time-to-solve
  CartPole-v1 on both backends with and without compile (`benchmarks.dqn`);
- `logging`: writing a 100,000-step rollout to a Rerun file (`benchmarks.rerun_logging`);
- `startup`: `mjxsuite train --env cartpole-mjx --steps 2000` in fresh processes sharing
  a fresh persistent compilation cache, once cold and three times warm: compile_s of each;
- `first-second`: one seed of DQN (`--preset quick`) solving CartPole-v1 (the run's judge, greedy
  mean >= 475 over 64 episodes), five separate runs: the median seconds after compile and with
  compile, beside the targets (`benchmarks.dqn.first_second_record`);
- `first-compile` (only when named): the README's `make train` command with `--no-compile-cache`
  in a fresh clone of this checkout's HEAD, three fresh processes: compile_s (eval.json) and
  where the rest of the wall time went;
- `gym-mujoco` (only when named): env-steps/s of Gymnasium's MuJoCo tasks with impl "jax" (and
  "warp" where it runs) beside Brax's look-alikes and Gymnasium's own vector env
  (`benchmarks.gym_mujoco`; `--batch` sets its sizes, default 4,096 and 32,768);
- `learning` (only when named; a GPU's work): every training to a threshold the suite claims,
  several seeds in one run each: solve rate, steps and seconds to solve, every seed's final
  return, the median and the worst (`benchmarks.learning`);
- `gym-vector` (only when named): env-steps/s of `gymnasium.make_vec("mjxsuite/Hopper-v5")` in
  Gymnasium's `JaxToTorch` with a torch MLP policy every step, beside our pure JAX loop and
  Gymnasium's own vector env over every core (`benchmarks.gym_vector`; `--batch`, default 4,096).

Records are a JSON list; every record has `kind`, `lib`, `device`; env-throughput records
also `env`, `num_envs`, `steps_per_s`, `compile_s`. A peer or section that cannot run
is recorded with `skipped` and the reason. The first record (`kind: meta`) says what
ran where. The bench itself does not use the persistent cache: its compile times are
cold compiles.

    mjxsuite bench [--quick] [--json FILE] [--sections env dqn logging startup gym-mujoco gym-vector learning]
    mjxsuite bench --plot FILE.json [--out docs/throughput.png]   # the plot, from saved records
    mjxsuite bench --table FILE.json                               # markdown tables, from saved records
"""

from __future__ import annotations

import json
import os
import platform as host_platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from agents import processes

SECTIONS = ("env", "dqn", "first-second", "logging", "startup", "first-compile", "gym-mujoco", "gym-vector",
            "learning")
DEFAULT_SECTIONS = ("env", "dqn", "first-second", "logging", "startup")  # gym-mujoco takes long, gym-vector needs torch: run them by name


def _cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return host_platform.processor() or None


def meta_record(quick: bool, sections) -> dict:
    import jax

    from benchmarks import peers

    device = jax.devices()[0]
    return {
        "kind": "meta", "lib": "mjxsuite", "device": device.device_kind, "platform": device.platform,
        "device_count": jax.device_count(), "cpu_count": len(os.sched_getaffinity(0)), "cpu": _cpu_model(),
        "python": host_platform.python_version(), "jax": jax.__version__,
        "versions": {p: peers.version(p) for p in ("mujoco", "mujoco-mjx", "brax", "gymnax", "playground")},
        "quick": quick, "sections": list(sections), "compile_cache": "off (cold compiles)",
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
    }


def env_section(quick: bool, batch=None, ours=("cartpole", "cartpole-mjx"), peers=("gymnax", "playground"),
                repeats=None) -> list[dict]:
    from benchmarks import env_throughput

    print("== env throughput: env-steps/s (random actions, auto-reset, median of runs; compile excluded) ==")
    records = env_throughput.throughput_records(ours=ours, peers=peers, batch=batch, quick=quick, repeats=repeats)
    ratios = env_throughput.ratio_records(records)
    for r in ratios:
        print(f"   {r['env']} / {r['peer']} {r['peer_env']} at {r['num_envs']:,} envs: {r['ratio']:.2f}x")
    return records + ratios


def gym_mujoco_section(quick: bool, batch=None, repeats=None) -> list[dict]:
    from benchmarks import gym_mujoco

    print("== Gymnasium's MuJoCo tasks: env-steps/s beside Brax's envs and Gymnasium's vector env ==")
    impls = ["jax", "warp"] if gym_mujoco.warp_available() else ["jax"]
    return gym_mujoco.run_benchmark(gym_mujoco.gymnasium_tasks(), batch or ([4096] if quick else [4096, 32768]),
                                    impls, repeats=repeats or 3)


def gym_vector_section(quick: bool, batch=None, repeats=None) -> list[dict]:
    from benchmarks import gym_vector

    print("== Gymnasium's vector API: make_vec + JaxToTorch + a torch policy, beside our JAX loop and Gymnasium's ==")
    records = []
    for num_envs in batch or [4096]:
        records += gym_vector.run_benchmark("mjxsuite/Hopper-v5", num_envs, steps=50 if quick else 200,
                                            repeats=repeats or (3 if quick else 5),
                                            gymnasium_steps=100 if quick else 300)
    return records


def dqn_section(quick: bool, peer_dqn: str | None = None) -> list[dict]:
    from benchmarks.dqn import dqn_records
    from benchmarks.dqn_peer import peer_dqn_records, peer_seeds

    print("== DQN: env-steps/s, updates/s, time-to-solve CartPole-v1 (greedy mean return >= 475) ==")
    records = dqn_records(quick)
    print("== DQN beside PureJaxRL's at matched configs: env-steps/s, compile excluded ==")
    return records + peer_dqn_records(peer_dqn, seeds=peer_seeds(quick))


def logging_section(quick: bool) -> list[dict]:
    from benchmarks.rerun_logging import bench_logging

    print("== Rerun logging ==")
    records = bench_logging(quick, train=not quick)
    for r in records:
        if r["kind"] == "log-rollout":
            print(f"   log a {r['steps']:,}-step rollout to .rrd: {r['total_s_median']:.3f} s median "
                  f"({r['total_s_min']:.3f} s best; {r['file_mb']:.1f} MB)")
        else:
            print(f"   train {r['steps']:,} steps with Rerun {r['logging']}: slowdown {100 * r['slowdown']:+.1f}%")
    return records


def startup_section(env: str = "cartpole-mjx", steps: int = 2000, warm_runs: int = 3) -> list[dict]:
    """`mjxsuite train` processes one after another sharing a fresh compilation cache: one cold,
    then `warm_runs` warm (their median is the figure: single warm runs gave 0.67 and 1.07 s
    on one H200 machine, 0.6 s three times on another)."""
    import jax

    print(f"== startup: `mjxsuite train --env {env} --steps {steps}`, 1 cold + {warm_runs} warm runs, "
          "fresh compile cache ==")
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "jax-cache"
        for run in range(1, warm_runs + 2):
            out = Path(tmp) / f"run{run}"
            command = [*processes.MJXSUITE, "train", "--env", env, "--steps", str(steps), "--out", str(out)]
            environ = {**os.environ, "MJXSUITE_COMPILE_CACHE": str(cache)}
            environ.pop("JAX_COMPILATION_CACHE_DIR", None)
            start = time.perf_counter()
            done = subprocess.run(command, env=environ, capture_output=True, text=True, check=False)
            wall = time.perf_counter() - start
            if done.returncode != 0:
                raise RuntimeError(f"startup run {run} failed ({done.returncode}): {done.stderr[-2000:]}")
            summary = json.loads((out / "eval.json").read_text())
            records.append({
                "kind": "startup", "lib": "mjxsuite", "env": env, "steps": steps, "run": run,
                "cache": "cold" if run == 1 else "warm", "compile_s": summary["compile_s"],
                "train_wall_s": summary["wall_s"], "process_wall_s": wall, "device": jax.devices()[0].device_kind,
            })
            r = records[-1]
            print(f"   run {run} ({r['cache']} cache): compile_s {r['compile_s']:.2f} (eval.json), "
                  f"train_run wall {r['train_wall_s']:.1f} s, process {r['process_wall_s']:.1f} s", flush=True)
    return records


def first_second_section(runs: int | None = None) -> list[dict]:
    from benchmarks.dqn import SOLVE_SEEDS, _describe, first_second_record

    print("== the first second: one seed solves CartPole-v1 (greedy mean >= 475 over 64 episodes) ==")
    record = first_second_record(runs=runs or SOLVE_SEEDS)
    print("   " + _describe(record), flush=True)
    return [record]


# The README's main job (`make train`), with the persistent caches off.
MAKE_TRAIN = ["train", "--env", "cartpole-mjx", "--out", "runs/cartpole-mjx", "--rerun", "runs/cartpole-mjx/train.rrd",
              "--overwrite", "--no-compile-cache"]


def first_compile_section(runs: int = 3) -> list[dict]:
    """`make train`'s command in a fresh clone of HEAD (nothing compiled, traced or cached there),
    `runs` fresh processes one after another, each with the caches off."""
    import jax

    root = Path(__file__).resolve().parents[1]
    print(f"== first compile: `mjxsuite {' '.join(MAKE_TRAIN)}` in a fresh clone, {runs} processes ==")
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", "--depth", "1", f"file://{root}", str(clone)], check=True)
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=clone, capture_output=True, text=True,
                              check=True).stdout.strip()
        environ = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
        environ.update(PYTHONPATH=str(clone), XDG_CACHE_HOME=str(Path(tmp) / "cache"))
        for run in range(1, runs + 1):
            start = time.perf_counter()
            done = subprocess.run([*processes.MJXSUITE, *MAKE_TRAIN], cwd=clone, env=environ, capture_output=True,
                                  text=True, check=False)
            wall = time.perf_counter() - start
            if done.returncode != 0:
                raise RuntimeError(f"first-compile run {run} failed ({done.returncode}): {done.stderr[-2000:]}")
            summary = json.loads((clone / "runs/cartpole-mjx/eval.json").read_text())
            records.append({"kind": "first-compile", "lib": "mjxsuite", "command": "mjxsuite " + " ".join(MAKE_TRAIN),
                            "commit": head, "run": run, "compile_s": summary["compile_s"],
                            "wall_parts_s": summary["wall_parts_s"], "train_wall_s": summary["wall_s"],
                            "process_wall_s": wall, "judged_chunks": summary.get("judged_chunks"),
                            "chunks": summary.get("chunks"), "mean_return": summary["mean_return"],
                            "device": jax.devices()[0].device_kind})
            parts = summary["wall_parts_s"]
            print(f"   run {run}: compile_s {summary['compile_s']:.2f}, judge {parts['judge']:.2f} + saves "
                  f"{parts['saves']:.2f} of train_run's {summary['wall_s']:.1f} s, process {wall:.1f} s", flush=True)
    compiles = [r["compile_s"] for r in records]
    print(f"   median compile_s {statistics.median(compiles):.2f} (runs: {', '.join(f'{c:.2f}' for c in compiles)})")
    return records


def learning_section() -> list[dict]:
    from benchmarks import learning

    return learning.section()


def run_bench(quick: bool = False, sections=DEFAULT_SECTIONS, batch=None, ours=("cartpole", "cartpole-mjx"),
              peers=("gymnax", "playground"), repeats=None, peer_dqn: str | None = None) -> list[dict]:
    """Every record of the chosen sections; a section that fails is recorded as skipped, with the reason."""
    from agents import jax_compile_cache

    jax_compile_cache.disable()  # report cold compile times
    records = [meta_record(quick, sections)]
    m = records[0]
    print(f"mjxsuite bench on {m['device']} ({m['platform']}, {m['cpu_count']} CPU cores), jax {m['jax']}, "
          f"python {m['python']}{' --quick' if quick else ''}", flush=True)
    runners = {
        "env": lambda: env_section(quick, batch, ours, peers, repeats),
        "dqn": lambda: dqn_section(quick, peer_dqn),
        "logging": lambda: logging_section(quick),
        "startup": startup_section,
        "first-second": lambda: first_second_section(1 if quick else None),
        "first-compile": first_compile_section,
        "gym-mujoco": lambda: gym_mujoco_section(quick, batch, repeats),
        "gym-vector": lambda: gym_vector_section(quick, batch, repeats),
        "learning": learning_section,
    }
    for section in sections:
        start = time.perf_counter()
        try:
            records += runners[section]()
        except ImportError as err:  # e.g. rerun-sdk missing on a benchmark-only install
            print(f"   skipped: {err}")
            records.append({"kind": section, "lib": "mjxsuite", "device": m["device"],
                            "skipped": f"{type(err).__name__}: {err}"})
        print(f"   ({section}: {time.perf_counter() - start:.0f} s)", flush=True)
    return records


# ---- reading saved records back ------------------------------------------------------
def load_records(path: str | os.PathLike) -> list[dict]:
    records = json.loads(Path(path).read_text())
    if not isinstance(records, list) or not all(isinstance(r, dict) and "kind" in r for r in records):
        raise ValueError(f"{path}: not a list of mjxsuite bench records")
    return records


def append_record(path: str | os.PathLike, record: dict) -> None:
    """`record` added to the end of the JSON list in `path` (a new list where there is no file): a script's `--json`."""
    path = Path(path)
    found = json.loads(path.read_text()) if path.exists() else []
    path.write_text(json.dumps([*found, record], indent=1) + "\n")


def write_records(path: str | os.PathLike, records: list[dict]) -> None:
    """`records` as the JSON list in `path`, written whole or not at all (`agents.checkpoint.atomic_write`)."""
    from agents.checkpoint import atomic_write

    atomic_write(Path(path), json.dumps(records, indent=1).encode())


def each_task_alone(module: str, argv: list[str], tasks: list[str], json_file: str | None) -> None:
    """`python -m module argv --tasks task` for every task in a process of its own, their records gathered into
    `json_file` after each: MuJoCo Warp's CUDA-graph captures of one task's programs must not meet the next
    task's (docs/mjx.md, "MuJoCo Warp and CUDA graphs")."""
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        for task in tasks:
            out = os.path.join(tmp, f"{task}.json")
            subprocess.run([sys.executable, "-m", module, *argv, "--tasks", task, "--json", out], check=False)
            if os.path.exists(out):
                with open(out) as f:
                    records += json.load(f)
            if json_file:
                write_records(json_file, records)


def without_options(argv: list[str], options: tuple[str, ...]) -> list[str]:
    """`argv` less the given options and their values."""
    kept, skipping = [], False
    for arg in argv:
        if arg.startswith("--"):
            skipping = arg.split("=")[0] in options
        if not skipping:
            kept.append(arg)
    return kept


def timed_program(program, *args, repeats: int = 3) -> tuple[float, float]:
    """(compile + first run seconds, median seconds of `repeats` further runs), each run waited for in full."""
    import jax
    start = time.perf_counter()
    jax.block_until_ready(program(*args))
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(program(*args))
        times.append(time.perf_counter() - start)
    return first, statistics.median(times)


def merge_records(old: list[dict], new: list[dict]) -> list[dict]:
    """`old` with its records of the kinds `new` holds replaced by `new`'s (`bench --merge`): one
    section re-run into a file of every section. The old meta record stays, with a note."""
    meta = [r for r in new if r["kind"] == "meta"]
    fresh = [r for r in new if r["kind"] != "meta"]
    kinds = {r["kind"] for r in fresh}
    kept = [dict(r) for r in old if r["kind"] not in kinds]
    for r in kept:
        if r["kind"] == "meta" and meta:
            note = f"{', '.join(meta[0]['sections'])} re-run alone at {meta[0]['date']}"
            r["note"] = f"{r['note']}; {note}" if r.get("note") else note
    return kept + fresh


def throughput_table(records: list[dict]) -> str:
    """Markdown: env-steps/s by batch size, ours beside each peer, with the ratio."""
    speed = {(r["lib"], r["env"], r["num_envs"]): r["steps_per_s"] for r in records
             if r["kind"] == "env-throughput" and r.get("steps_per_s")}
    columns = [("mjxsuite", "cartpole"), ("gymnax", "CartPole-v1"), None,
               ("mjxsuite", "cartpole-mjx"), ("playground", "CartpoleBalance"), None]
    sizes = sorted({n for (_, _, n) in speed})
    if not sizes:
        return ""
    head = ["num_envs", "cartpole", "gymnax CartPole-v1", "ratio", "cartpole-mjx", "Playground CartpoleBalance",
            "ratio"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---:|" * len(head)]
    for n in sizes:
        cells = [f"{n:,}"]
        for i, column in enumerate(columns):
            if column is None:
                ours, theirs = speed.get((*columns[i - 2], n)), speed.get((*columns[i - 1], n))
                cells.append(f"{ours / theirs:.2f}x" if ours and theirs else "–")
            else:
                value = speed.get((*column, n))
                cells.append(f"{value:,.0f}" if value else "–")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _default_axis(records: list[dict]) -> str:
    """The seed axis `train_run` uses on the device of these records."""
    from agents.device_options import default_seed_axis

    meta = next((m for m in records if m["kind"] == "meta"), {})
    return default_seed_axis(meta.get("platform", "gpu"))


def dqn_table(records: list[dict]) -> str:
    """Markdown: one row per env and seed count; speed from the throughput runs, times from
    the solve runs (one seed: the median of several separately seeded runs)."""
    rows: dict[tuple[str, int], dict] = {}
    for r in records:
        if r["kind"] in ("dqn-solve", "dqn-throughput"):
            axis = r.get("seed_axis") or _default_axis(records)  # solve runs use the device's default
            seeds = f"{r['seeds']} ({axis})" if r["seeds"] > 1 else "1"
            if r.get("preset", "default") != "default":
                seeds += f", `--preset {r['preset']}`"
            rows.setdefault((r["env"], seeds), {})[r["kind"]] = r
    if not rows:
        return ""
    head = ["env", "seeds", "env-steps/s", "updates/s", "compile s", "solved", "time-to-solve (with compile)",
            "time-to-solve (without)", "median solve step"]
    lines = ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    for (env, seeds), kinds in rows.items():
        speed, solve = kinds.get("dqn-throughput", {}), kinds.get("dqn-solve", {})
        with_compile, step = solve.get("time_to_solve_s"), solve.get("median_solve_step")
        runs = f" (median of {solve['runs']} runs)" if solve.get("runs", 1) > 1 else ""
        lines.append("| " + " | ".join([
            env, seeds,
            f"{speed['steps_per_s']:,.0f}" if speed else "–",
            f"{speed['updates_per_s']:,.0f}" if speed else "–",
            f"{(solve or speed)['compile_s']:.1f}",
            solve.get("solved", "–"),
            f"{with_compile:.1f} s{runs}" if with_compile is not None else "–",
            f"{solve['time_to_solve_excl_compile_s']:.1f} s" if with_compile is not None else "–",
            f"{step:,.0f}" if step is not None else "–",
        ]) + " |")
    return "\n".join(lines)


def peer_dqn_table(records: list[dict]) -> str:
    """Markdown: our DQN and the PureJaxRL-style peer, env-steps/s by matched config and seed count."""
    speed = {(r["lib"], r["config"], r["seeds"]): r["steps_per_s"] for r in records
             if r["kind"] == "dqn-peer" and r.get("steps_per_s")}
    rows = sorted({(config, seeds) for (_, config, seeds) in speed}, key=lambda k: (k[0] != "1 env", k[1]))
    if not rows:
        return ""
    lines = ["| config | seeds | mjxsuite env-steps/s | PureJaxRL env-steps/s | mjxsuite / PureJaxRL |",
             "|---|---:|---:|---:|---:|"]
    for config, seeds in rows:
        ours, peer = speed.get(("mjxsuite", config, seeds)), speed.get(("purejaxrl", config, seeds))
        lines.append(f"| {config} | {seeds:,} | {ours:,.0f} | {peer:,.0f} | {ours / peer:.2f}x |" if ours and peer
                     else f"| {config} | {seeds:,} | {ours or 0:,.0f} | {peer or 0:,.0f} | – |")
    return "\n".join(lines)


def replay_table(records: list[dict]) -> str:
    """Markdown: µs per replay operation inside a `lax.scan`, ours and flashbax's, with the ratio."""
    rows = [r for r in records if r["kind"] in ("uniform", "prioritized") and "ours_scan_us" in r]
    if not rows:
        return ""
    lines = ["| capacity | buffer | op | ours µs | flashbax µs | ratio (> 1: ours faster) |",
             "|---:|---|---|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['capacity']:,} | {r['kind']} | {r['op']} | {r['ours_scan_us']:.2f} | "
                     f"{r['fbx_scan_us']:.2f} | {r['scan_ratio']:.2f}x |")
    return "\n".join(lines)


def tables(records: list[dict]) -> str:
    """All the markdown tables the saved records make, with the run's hardware line."""
    meta = next((r for r in records if r["kind"] == "meta"), {})
    hardware = (f"Measured on {meta.get('device', '?')} ({meta.get('cpu_count', '?')} cores of "
                f"{meta.get('cpu') or 'a CPU'}), jax {meta.get('jax', '?')}, python {meta.get('python', '?')}, "
                f"{meta.get('date', '')}{' (--quick)' if meta.get('quick') else ''}.")
    parts = [hardware]
    throughput = throughput_table(records)
    if throughput:
        parts += ["", throughput]
    for r in records:
        if r["kind"] == "env-throughput" and r.get("skipped"):
            parts.append(f"\n{r['lib']} {r['env']} skipped at {r['num_envs']:,} envs: {r['skipped']}")
    dqn = dqn_table(records)
    if dqn:
        parts += ["", dqn]
    peer = peer_dqn_table(records)
    if peer:
        parts += ["", "DQN beside PureJaxRL's (`--peer-dqn`), env-steps/s of all seeds together, compile excluded:",
                  "", peer]
    for r in records:
        if r["kind"] == "dqn-peer" and r.get("skipped"):
            parts.append(f"\nPureJaxRL DQN skipped: {r['skipped']}")
    for r in records:
        if r["kind"] == "dqn-seed-scaling":
            axis = {"vmap": "vmapped ", "map": "mapped (`lax.map`) "}[r["seed_axis"]]
            parts.append(f"\n{r['env']}: {r['seeds']} {axis}seeds give {r['ratio']:.1f}x the env-steps/s of one "
                         f"seed, i.e. {r['seeds']} times the work in {r['time_ratio']:.2f}x the time.")
        elif r["kind"] == "dqn-article-setup":
            parts.append(f"\nArticle setup (1 env, MLP 64-64-64, batch 32, buffer 512, 20,000 steps): "
                         f"{r['steps_per_s']:,.0f} env-steps/s, median of "
                         f"{', '.join(f'{v:,.0f}' for v in r['steps_per_s_runs'])} (compile {r['compile_s']:.1f} s "
                         "excluded).")
        elif r["kind"] == "train-rerun":
            parts.append(f"\nTraining {r['steps']:,} steps with `--rerun` ({r['logging']}): median wall "
                         f"{r['median_with_s']:.1f} s vs {r['median_without_s']:.1f} s without "
                         f"({100 * r['slowdown']:+.1f}%); the logger's own time: {100 * r['logger_share']:.1f}% of the run.")
        elif r["kind"] == "log-rollout":
            parts.append(f"\nLogging a {r['steps']:,}-step rollout to a Rerun file: {r['total_s_median']:.2f} s "
                         f"(median; {r['file_mb']:.1f} MB).")
    startup = startup_line(records)
    if startup:
        parts += ["", startup]
    replay = replay_table(records)
    if replay:
        parts += ["", "Replay buffers against flashbax, µs per operation inside a `lax.scan` (add = 1 transition, "
                  "sample = 32):", "", replay]
    return "\n".join(parts)


def startup_line(records: list[dict]) -> str | None:
    """compile_s of the cold `mjxsuite train` and the median of the warm ones."""
    runs = [r for r in records if r["kind"] == "startup"]
    if not runs:
        return None
    cold = [r["compile_s"] for r in runs if r["cache"] == "cold"]
    warm = [r["compile_s"] for r in runs if r["cache"] == "warm"]
    line = f"`mjxsuite train --env {runs[0]['env']} --steps {runs[0]['steps']}` in fresh processes: compile_s"
    if cold:
        line += f" {cold[0]:.2f} with a cold compile cache"
    if warm:
        each = f" (median of {', '.join(f'{s:.2f}' for s in warm)})" if len(warm) > 1 else ""
        line += f"{',' if cold else ''} {statistics.median(warm):.2f} warm{each}"
    return line + "."


def plot(records: list[dict], out: str | os.PathLike) -> Path:
    """Env-steps/s against batch size, log-log, one line per library and env."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as err:
        raise SystemExit(f"mjxsuite bench --plot needs matplotlib (pip install 'mjxsuite[bench]'): {err}")
    meta = next((r for r in records if r["kind"] == "meta"), {})
    lines: dict[tuple[str, str], list[tuple[int, float]]] = {}
    for r in records:
        if r["kind"] == "env-throughput" and r.get("steps_per_s"):
            lines.setdefault((r["lib"], r["env"]), []).append((r["num_envs"], r["steps_per_s"]))
    if not lines:
        raise ValueError("no env-throughput records to plot")
    styles = {"mjxsuite": "-", "gymnax": "--", "playground": "--"}
    colors = {"cartpole": "C0", "CartPole-v1": "C0", "cartpole-mjx": "C1", "CartpoleBalance": "C1"}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for (lib, env), points in sorted(lines.items()):
        points.sort()
        ax.plot([n for n, _ in points], [s for _, s in points], styles.get(lib, ":"), marker="o",
                color=colors.get(env), label=f"{lib} {env}")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("parallel envs (batch size)")
    ax.set_ylabel("env steps / s")
    ax.set_title(f"Env throughput on {meta.get('device', '?')} (random actions, auto-reset)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
