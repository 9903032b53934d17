"""Seeds trained by several processes (`agents.processes`, `mjxsuite train --processes K`): what an
MJX task does on a host with several GPUs, forced here on the CPU for the analytic CartPole (the
quickest to compile; the launcher treats every task alike). The reference is a one-process
run of the same seeds: each process trains its slice with the keys the whole run gives it, so
every seed ends bit for bit as it does there."""

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from agents import checkpoint, load_policy, processes
from agents.cli import main as cli_main
from agents.run import load_agent

# Slow run: child processes per GPU (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

DQN_ARGS = ["--env", "cartpole", "--seeds", "2", "--steps", "600", "--learning_starts", "64", "--batch_size", "32",
            "--buffer_size", "256", "--eval_every", "100", "--eval_episodes", "4", "--hidden", "16",
            "--judge-every", "1", "--checkpoint-seconds", "0"]
CLI = processes.MJXSUITE


def same_params(a, b) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A one-process and a two-process run of the same two seeds."""
    one, two = tmp_path_factory.mktemp("one") / "run", tmp_path_factory.mktemp("two") / "run"
    assert cli_main(["train", *DQN_ARGS, "--out", str(one)]) == 0
    assert cli_main(["train", *DQN_ARGS, "--out", str(two), "--processes", "2"]) == 0
    return one, two


def test_two_processes_train_each_seed_as_one_process_does(runs):
    one, two = runs
    assert same_params(load_agent(one)[3], load_agent(two)[3])
    for k, child in enumerate(sorted((two / processes.PROCESSES_DIR).iterdir())):
        assert checkpoint.load_config(child).seed_slice == (k, k + 1)
        ours = [json.loads(line)["eval_return"] for line in (child / "metrics.jsonl").read_text().splitlines()]
        theirs = [json.loads(line)["eval_return"][k] for line in (one / "metrics.jsonl").read_text().splitlines()]
        assert np.array_equal(np.ravel(ours), theirs)  # every judged chunk, not just the end


def test_the_merged_run_reads_as_one_run(runs, capsys):
    """eval.json has one row per seed, the keys of a one-process run and its best seed;
    load_policy, eval and best_seed read every seed from the processes' directories."""
    one, two = runs
    merged, single = (json.loads((d / "eval.json").read_text()) for d in (two, one))
    assert set(merged) == set(single) | {"processes"} and merged["processes"] == 2
    for key in ("seeds", "mean_return", "best_seed", "solve_step", "agent", "env", "chunks"):
        assert merged[key] == single[key], key
    assert checkpoint.load_config(two) == checkpoint.load_config(one)
    obs = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32)
    for seed_index in (0, 1, None):
        assert np.array_equal(load_policy(two, seed_index=seed_index)(obs), load_policy(one, seed_index=seed_index)(obs))
    assert checkpoint.load_best_returns(two) == checkpoint.load_best_returns(one)
    capsys.readouterr()
    assert cli_main(["eval", "--checkpoint", str(two), "--episodes", "4"]) == 0
    assert capsys.readouterr().out.count("seed ") == 2


def test_resume_trains_the_unfinished_process_only(runs, tmp_path, capsys):
    """A process killed before its first checkpoint starts again; the finished one is left as it is."""
    one, two = runs
    run = tmp_path / "run"
    shutil.copytree(two, run)
    child = run / processes.PROCESSES_DIR / "1"
    for name in (checkpoint.STATE_FILE, checkpoint.POLICY_FILE, checkpoint.PROGRESS_FILE, "eval.json",
                 checkpoint.METRICS_FILE):
        (child / name).unlink()
    (run / "eval.json").unlink()
    capsys.readouterr()
    assert cli_main(["train", "--out", str(run), "--resume"]) == 0
    said = capsys.readouterr().out
    assert "process 1 (seed 1): training" in said and "process 0" not in said.split("process 1 (seed 1): done")[0]
    assert same_params(load_agent(run)[3], load_agent(one)[3])
    assert json.loads((run / "eval.json").read_text())["mean_return"] == json.loads((one / "eval.json").read_text())["mean_return"]


def test_a_failing_process_fails_the_run_naming_its_log(runs, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(runs[1], run)
    child = run / processes.PROCESSES_DIR / "1"
    (child / "eval.json").unlink()
    (child / checkpoint.CONFIG_FILE).write_text("{ damaged")
    capsys.readouterr()
    assert cli_main(["train", "--out", str(run), "--resume"]) == 1
    err = capsys.readouterr().err
    assert f"process 1 (seed 1) failed with exit status 1; its log: {child / processes.LOG_FILE}" in err
    assert "is damaged" in err  # the log's last line says why


def test_how_many_processes(monkeypatch):
    """An MJX task on several GPUs takes as many processes as split the seeds (as choose_devices
    splits them over devices); --devices K asks for K; an analytic task or one GPU: one process;
    seeds that do not split are refused naming the option, its value and the fix."""
    two_gpus = ["0", "1"]
    assert processes.count("cartpole-mjx", 4, None, None, two_gpus) == 2
    assert processes.count("cartpole-mjx", 3, None, None, two_gpus) == 1
    assert processes.count("cartpole-mjx", 4, 1, None, two_gpus) == 1
    assert processes.count("cartpole", 4, None, None, two_gpus) == 1  # one program over the devices, as ever
    assert processes.count("cartpole-mjx", 4, None, None, ["0"]) == 1
    assert processes.count("cartpole", 4, None, 2, []) == 2  # forced, on a CPU
    with pytest.raises(ValueError, match=r"--devices 2: 3 seeds do not split evenly over 2 processes .* use --seeds 2 or 4, or --devices 1"):
        processes.count("cartpole-mjx", 3, 2, None, two_gpus)
    with pytest.raises(ValueError, match=r"--processes 4: 6 seeds .* --processes 3"):
        processes.count("cartpole-mjx", 6, None, 4, [])
    with pytest.raises(ValueError, match="drop --devices 2"):
        processes.count("cartpole-mjx", 4, 2, 2, two_gpus)
    with pytest.raises(ValueError, match="between 1 and the 2 local GPUs"):
        processes.count("cartpole-mjx", 4, 4, None, two_gpus)
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "2,3")
    monkeypatch.setenv("JAX_PLATFORMS", "")
    assert processes.local_gpus() == ["2", "3"]
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    assert processes.local_gpus() == []


@pytest.mark.slow
def test_ctrl_c_stops_every_process_with_a_checkpoint_and_resume_ends_as_one_process(runs, tmp_path):
    """SIGINT to the parent reaches each child once: each saves and stops; --resume then ends with
    the parameters of the uninterrupted one-process run."""
    one, _ = runs
    run = tmp_path / "run"
    steps = ["--steps", "20000"]  # long enough to be stopped; the reference below trains as long
    parent = subprocess.Popen([*CLI, "train", *DQN_ARGS, *steps, "--out", str(run), "--processes", "2"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    states = [run / processes.PROCESSES_DIR / str(k) / checkpoint.STATE_FILE for k in range(2)]
    deadline = time.monotonic() + 300
    while not all(state.is_file() for state in states) and parent.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)
    parent.send_signal(signal.SIGINT)
    out, err = parent.communicate(timeout=300)
    assert parent.returncode == 130, out + err
    assert "stopped by SIGINT; checkpoint saved" in out
    for k in range(2):
        log = (run / processes.PROCESSES_DIR / str(k) / processes.LOG_FILE).read_text()
        assert "stopped by SIGINT; checkpoint saved" in log and "again: exiting now" not in log
    done = subprocess.run([*CLI, "train", "--out", str(run), "--resume"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    whole = run.parent / "whole"
    assert cli_main(["train", *DQN_ARGS, *steps, "--out", str(whole)]) == 0
    assert same_params(load_agent(run)[3], load_agent(whole)[3])


def _alive(pid: int) -> bool:
    try:
        status = open(f"/proc/{pid}/status").read()
    except FileNotFoundError:
        return False
    return "\nState:\tZ" not in status  # a zombie has ended


def _children_of(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:  # field 4, the parent's pid
                found.append(int(stat.parent.name))
        except (OSError, ValueError, IndexError):
            pass
    return found


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_children_stop_when_their_parent_is_killed(tmp_path):
    """Case 54: SIGKILL of a --processes parent used to leave its children training. Each child
    gets SIGTERM when its parent ends (`signals.die_with_parent`): it stops, as on a Ctrl-C. Killed
    as soon as both started, while they import (a child in training stops the same way, saved)."""
    run = tmp_path / "run"
    parent = subprocess.Popen([*CLI, "train", *DQN_ARGS, "--steps", "200000", "--out", str(run), "--processes", "2"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while len(children := _children_of(parent.pid)) < 2:
        assert parent.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 120
    while any(map(_alive, children)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(map(_alive, children))  # unsignalled, each would train its 200,000 steps for minutes
    for k in range(2):  # ended by the signal (before or after their handlers), not by an error
        assert "Traceback" not in (run / processes.PROCESSES_DIR / str(k) / processes.LOG_FILE).read_text()


@pytest.mark.heavy
def test_ppo_in_two_processes_equals_one_process(tmp_path):
    from tests.test_agents_cli import TINY_PPO_ARGS

    argv = ["train", "--env", "pendulum-mjx", "--agent", "ppo", "--seeds", "2", *TINY_PPO_ARGS, "--judge-every", "1"]
    assert cli_main([*argv, "--out", str(tmp_path / "one")]) == 0
    assert cli_main([*argv, "--out", str(tmp_path / "two"), "--processes", "2"]) == 0
    assert same_params(load_agent(tmp_path / "one")[3], load_agent(tmp_path / "two")[3])
    returns = [json.loads((tmp_path / d / "eval.json").read_text())["mean_return"] for d in ("one", "two")]
    assert returns[0] == returns[1]


def test_the_parent_keeps_jax_off_the_gpus_and_starts_its_processes_without_mjx(tmp_path):
    """On a host with several GPUs the command decides on processes before JAX's backend starts
    (a started backend takes memory on every GPU the children train on), then keeps its own JAX on
    the first GPU without reserving memory. Everything it does before it starts the processes (the
    options, the agent, the config, the directories) needs no MJX, which loads MuJoCo Warp, and no
    device (`envs.spec`), so they start at once. Two GPUs are pretended; the processes are replaced
    by a check of what the parent has loaded."""
    code = """
import sys
from jax._src import xla_bridge
from agents import processes
processes.local_gpus = lambda: ["0", "1"]
def check(gpus):
    print("backend started:", xla_bridge.backends_are_initialized(), "gpus:", gpus)
processes.keep_off_the_gpus = check
def train(out, run, total_chunks, options, gpus):
    print("mjx:", "mujoco.mjx" in sys.modules, "backend:", xla_bridge.backends_are_initialized(), "agent:", run.agent)
    sys.exit(0)
processes.train = train
from agents.console import main
sys.exit(main())
"""
    done = subprocess.run([sys.executable, "-c", code, "train", "--env", "hopper", "--seeds", "2", "--out",
                           str(tmp_path / "run")], capture_output=True, text=True, timeout=120)
    assert "backend started: False gpus: ['0', '1']" in done.stdout, done.stdout + done.stderr
    assert "mjx: False backend: False agent: td3" in done.stdout, done.stdout + done.stderr
    assert checkpoint.process_dirs(tmp_path / "run") is not None


def test_what_runs_in_one_process_is_refused_before_anything_starts(tmp_path, capsys):
    from agents.cli import UsageError

    with pytest.raises(UsageError, match="--rerun runs in one process.*drop --rerun, or add --devices 1"):
        cli_main(["train", *DQN_ARGS, "--processes", "2", "--rerun", str(tmp_path / "x.rrd")])
    assert cli_main(["train", *DQN_ARGS, "--processes", "3"]) == 2
    assert "--processes 3: 2 seeds do not split evenly over 3 processes" in capsys.readouterr().err
    assert not (tmp_path / "x.rrd").exists()


def test_a_new_run_over_a_run_of_processes_removes_their_directories(runs, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(runs[1], run)
    checkpoint.start_run(run, checkpoint.load_config(run))  # what --overwrite with --devices 1 does first
    assert not (run / processes.PROCESSES_DIR).exists() and checkpoint.process_dirs(run) is None


def test_tied_seeds_are_told_apart_over_every_seed_as_in_one_process(runs, tmp_path):
    """The merge breaks ties by `break_ties` over all the seeds' parameters, as one process does."""
    from agents.run import break_ties

    one, two = runs
    run = tmp_path / "run"
    shutil.copytree(two, run)
    for child in (run / processes.PROCESSES_DIR).iterdir():
        record = json.loads((child / "eval.json").read_text())
        (child / "eval.json").write_text(json.dumps({**record, "mean_return": [10.0]}))
    saved = checkpoint.load_config(run)
    merged = processes.merge(run, saved, processes.children_of(run, []), time.perf_counter())
    env_name, _, agent, params = load_agent(one)
    best, measured = break_ties(agent, env_name, saved.env_options, params, [10.0, 10.0], saved.seed)
    assert merged.best_seed == best
    merged_eval = json.loads((run / "eval.json").read_text())
    assert merged_eval["best_seed"] == merged.best_seed and merged_eval["tie_break_return"] == pytest.approx([measured[0], measured[1]])


def test_the_merge_takes_the_tie_break_its_processes_measured(runs, tmp_path, monkeypatch):
    """Seeds tied within their process were measured there (keyed by their index in the run, as one
    process does): the merge takes those returns rather than measuring again, and makes no env and
    loads no parameters (for an MJX task: MJX, MuJoCo Warp and a device after the processes end).
    Shown by returns the opposite of the real ones, which only a merge that reads them follows."""
    from agents import run as run_module
    from agents.run import break_ties

    one, two = runs
    run = tmp_path / "run"
    shutil.copytree(two, run)
    saved = checkpoint.load_config(run)
    env_name, _, agent, params = load_agent(one)
    real_best, measured = break_ties(agent, env_name, saved.env_options, params, [10.0, 10.0], saved.seed)
    made_up = {0: measured[1], 1: measured[0]} if measured[0] != measured[1] else {0: 1.0, 1: 2.0}
    for k, child in enumerate(sorted((run / processes.PROCESSES_DIR).iterdir())):
        record = json.loads((child / "eval.json").read_text())
        (child / "eval.json").write_text(json.dumps({**record, "mean_return": [10.0], "tie_break_return": [made_up[k]]}))
    monkeypatch.setattr(run_module, "load_agent", lambda *_: pytest.fail("the merge made the env"))
    merged = processes.merge(run, saved, processes.children_of(run, []), time.perf_counter())
    assert merged.best_seed == max((0, 1), key=lambda i: (made_up[i], -i))
    if measured[0] != measured[1]:
        assert merged.best_seed != real_best
