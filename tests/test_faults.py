"""Fault injection (issue #17): kills, damaged files, a full disk, NaN physics, nonsense input.

docs/reliability.md lists the guarantees these tests prove."""

import errno
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import serialization

import envs
from agents import DQN, DQNConfig, checkpoint, processes, train_run
from agents.cli import main as cli_main
from agents.run import CLOCK_KEYS, seed_keys

# Slow run: subprocess runs stopped by signals and kill -9 (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

CONFIG = DQNConfig(total_steps=600, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                   eval_episodes=4, hidden=(16,))
CONFIG_ARGS = ["--steps", "600", "--learning_starts", "64", "--batch_size", "32", "--buffer_size", "256",
               "--eval_every", "100", "--eval_episodes", "4", "--hidden", "16", "--judge-every", "1"]
SEEDS = 2


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The uninterrupted run every interrupted one must end equal to."""
    out = tmp_path_factory.mktemp("reference")
    assert cli_main(["train", "--env", "cartpole", "--seeds", str(SEEDS), "--out", str(out), *CONFIG_ARGS]) == 0
    return out


def final_state(out):
    run = checkpoint.load_config(out)
    template = jax.eval_shape(jax.vmap(DQN(run.config, envs.make(run.env)).init), seed_keys(run.seed, run.seeds))
    return checkpoint.load_state(out, run.env, template)


def metrics_without_timings(out):
    records = [json.loads(line) for line in (out / checkpoint.METRICS_FILE).read_text().splitlines()]
    return [{k: v for k, v in r.items() if k not in CLOCK_KEYS} for r in records]


def assert_same_run(out, reference):
    (state, chunks), (expected, expected_chunks) = final_state(out), final_state(reference)
    assert chunks == expected_chunks == CONFIG.num_chunks
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(expected), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert metrics_without_timings(out) == metrics_without_timings(reference)
    assert json.loads((out / "eval.json").read_text())["mean_return"] == \
        json.loads((reference / "eval.json").read_text())["mean_return"]


# Runs the CLI with every rename slowed down, so a save (temp file written, rename pending)
# lasts long enough to be killed in the middle of.
SLOW_SAVES = """
import os, sys, time
rename = os.replace
def slow_rename(src, dst):
    time.sleep(0.3)
    rename(src, dst)
os.replace = slow_rename
from agents.cli import main
sys.exit(main(sys.argv[1:]))
"""


def start_training(out):
    command = [sys.executable, "-c", SLOW_SAVES, "train", "--env", "cartpole", "--seeds", str(SEEDS), "--out",
               str(out), "--checkpoint-seconds", "0", *CONFIG_ARGS]
    with open(out.parent / "stderr.txt", "w") as stderr:  # a file, not a pipe nobody reads while it runs
        return subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=stderr)


def wait_for(condition, out, process, timeout=120.0):
    deadline = time.monotonic() + timeout
    while not condition():
        assert process.poll() is None, f"training ended before the kill: {(out.parent / 'stderr.txt').read_text()}"
        assert time.monotonic() < deadline, "timed out waiting to kill"
        time.sleep(0.01)


def _chunks_logged(out) -> int:
    """Lines in the run's metrics.jsonl so far: the chunks it has trained (0 before the first)."""
    path = out / checkpoint.METRICS_FILE
    return len(path.read_text().splitlines()) if path.is_file() else 0


KILL_MOMENTS = {
    "before the first checkpoint": lambda out: (out / checkpoint.CONFIG_FILE).is_file(),
    "during a save": lambda out: any(out.glob("*.ckpt.tmp")),
    "between saves": lambda out: (out / checkpoint.PROGRESS_FILE).is_file()
    and json.loads((out / checkpoint.PROGRESS_FILE).read_text())["chunks_done"] >= 2,
}


# "between saves" runs in the slow run (the default run stays under 6 minutes on 2 cores): the signal
# tests resume from a checkpoint taken between chunks there too.
@pytest.mark.parametrize("moment", [pytest.param(moment, marks=pytest.mark.slow if moment == "between saves" else ())
                                    for moment in KILL_MOMENTS])
def test_kill_9_then_resume_ends_as_the_uninterrupted_run(tmp_path, reference, moment):
    out = tmp_path / "run"
    process = start_training(out)
    try:
        wait_for(lambda: KILL_MOMENTS[moment](out), out, process)
        time.sleep(random.Random(moment).uniform(0.0, 0.3))  # somewhere in the next rename or two
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    assert not (out / "eval.json").exists()  # the kill really cut the run short
    if (out / checkpoint.STATE_FILE).exists():  # the previous good checkpoint survived the kill...
        logged = _chunks_logged(out)
        # ...at most one interval (a chunk) behind the save under way, whose write overlaps the next chunk
        assert logged - 2 <= final_state(out)[1] < CONFIG.num_chunks
    assert cli_main(["train", "--out", str(out), "--resume"]) == 0  # env, seeds, config come from --out
    assert_same_run(out, reference)


def damage(path, how):
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "garbled":  # a few bytes in the middle, as a bad disk sector would
        middle = len(data) // 2
        path.write_bytes(data[:middle] + bytes(b ^ 0x5A for b in data[middle:middle + 8]) + data[middle + 8:])
    elif how == "older format":  # format 1: the bare leaves
        path.write_bytes(serialization.msgpack_serialize({"0": np.zeros(3)}))


@pytest.mark.parametrize("name,how,message", [
    (checkpoint.CONFIG_FILE, "truncated", "is damaged"),
    (checkpoint.CONFIG_FILE, "garbled", "is damaged"),
    (checkpoint.STATE_FILE, "truncated", "is truncated"),
    (checkpoint.STATE_FILE, "garbled", "is corrupted"),
    (checkpoint.STATE_FILE, "older format", "older mjxsuite"),
    (checkpoint.POLICY_FILE, "truncated", "is truncated"),
    (checkpoint.POLICY_FILE, "garbled", "is corrupted"),
])
def test_damaged_files_are_refused_naming_the_file(tmp_path, reference, capsys, name, how, message):
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    damage(out / name, how)
    reads = ["train", "--out", str(out), "--resume"] if name != checkpoint.POLICY_FILE else \
        ["eval", "--checkpoint", str(out), "--episodes", "1"]
    assert cli_main(reads) == 1  # a runtime failure, not a usage error
    err = capsys.readouterr().err
    assert str(out / name) in err and message in err
    assert "start the run again" in err or "train the agent again" in err or "restore it" in err


def test_a_run_directory_of_the_msgpack_format_is_refused_not_restarted(tmp_path, reference, capsys):
    """An older mjxsuite's run directory (train_state.msgpack) is refused by name: a resume
    that started over would silently drop its training."""
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    for name, older in checkpoint.OLDER_FILES.items():
        (out / name).rename(out / older)
    assert cli_main(["train", "--out", str(out), "--resume"]) == 1
    err = capsys.readouterr().err
    assert str(out / checkpoint.OLDER_FILES[checkpoint.STATE_FILE]) in err and "older mjxsuite" in err


def test_a_checkpoint_from_another_env_is_refused(tmp_path, reference, capsys):
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    record = json.loads((out / checkpoint.CONFIG_FILE).read_text())
    (out / checkpoint.CONFIG_FILE).write_text(json.dumps({**record, "env": "acrobot"}))
    assert cli_main(["eval", "--checkpoint", str(out), "--episodes", "1"]) == 1
    assert "was written for env 'cartpole', not 'acrobot'" in capsys.readouterr().err


def test_a_full_disk_fails_clearly_and_keeps_the_previous_checkpoint(tmp_path, reference, monkeypatch, capsys):
    out = tmp_path / "run"
    syncs = []

    def fsync_then_disk_full(fd):
        syncs.append(fd)
        if len(syncs) > 5:  # config.json, metrics.jsonl and the first checkpoint's 3 files fit, then the disk is full
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(checkpoint.os, "fsync", fsync_then_disk_full)
    code = cli_main(["train", "--env", "cartpole", "--seeds", str(SEEDS), "--out", str(out),
                     "--checkpoint-seconds", "0", *CONFIG_ARGS])
    assert code == 1
    err = capsys.readouterr().err
    assert "No space left on device" in err and str(out / checkpoint.POLICY_FILE) in err and "intact" in err
    assert not list(out.glob("*.tmp"))
    assert final_state(out)[1] == 1  # the first checkpoint, whole
    monkeypatch.undo()  # space freed
    assert cli_main(["train", "--out", str(out), "--resume"]) == 0
    assert_same_run(out, reference)


class ExplodingCartPole(envs.CartPoleMjx):
    """The physics turns NaN once the cart is 2 cm right of the centre (as an unstable
    simulation would); nearer the centre it is the usual CartPole. A second `mjx.step` with
    a huge motor does the same but triples the compile time."""

    def post_step(self, prev, data):
        return data.replace(qvel=jnp.where(prev.qpos[0] > 0.02, jnp.nan, data.qvel))


@pytest.mark.slow
def test_nan_physics_ends_episodes_counted_and_nothing_nan_is_learned():
    dqn = DQN(CONFIG, envs.TimeLimit(ExplodingCartPole(), 500))
    ts = jax.jit(dqn.init)(jax.random.PRNGKey(0))
    chunk = jax.jit(dqn.chunk)
    nan_episodes = 0
    for _ in range(2):
        ts, metrics = chunk(ts)
        nan_episodes += int(metrics["nan_episodes"])
    assert nan_episodes > 10
    kept = int(ts.buffer.size)
    assert 0 < kept == int(ts.env_steps) - nan_episodes  # every finite transition, no exploded one
    assert np.isfinite(np.asarray(ts.buffer.data)[:kept]).all()
    for leaf in jax.tree.leaves((ts.params, ts.target_params, ts.opt_state)):
        assert np.isfinite(np.asarray(leaf)).all()


@pytest.mark.parametrize("args,message", [
    (["--steps", "0"], "argument --steps: must be an integer >= 1, got 0"),
    (["--steps", "-5"], "argument --steps: must be an integer >= 1, got -5"),
    (["--seeds", "0"], "argument --seeds: must be an integer >= 1, got 0"),
    (["--checkpoint-seconds", "nan"], "argument --checkpoint-seconds: must be a finite number >= 0, got nan"),
    (["--learning_rate", "nan"], "DQNConfig.learning_rate must be a finite number > 0, got nan"),
    (["--gamma", "1.5"], "DQNConfig.gamma must be in [0, 1], got 1.5"),
    (["--epsilon_end", "-0.1"], "DQNConfig.epsilon_end must be in [0, 1], got -0.1"),
    (["--num_envs", "3"], "DQNConfig.eval_every must be a multiple of num_envs * train_every (3), got 1000"),
    (["--steps", "500"], "DQNConfig.total_steps must be at least eval_every (1000"),
])
def test_nonsense_options_are_refused_before_anything_compiles(capsys, args, message):
    with pytest.raises(SystemExit) as exit:
        cli_main(["train", "--env", "cartpole", *args])
    assert exit.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("name,option,value", [
    ("cartpole", "masspole", -0.1), ("cartpole", "length", 0.0), ("cartpole", "tau", 0.0),
    ("cartpole-mjx", "x_threshold", -1.0), ("acrobot", "dt", 0.0), ("acrobot", "link_mass_1", -1.0),
    ("pendulum-mjx", "max_speed", float("inf")), ("cartpole-swingup-mjx", "reset_noise", -0.01),
    ("cartpole", "episode_length", 0),
])
def test_out_of_range_env_overrides_are_refused(name, option, value):
    with pytest.raises(ValueError, match=rf"{option} must be .*, got {value!r}"):
        envs.make(name, **{option: value})


def test_usage_errors_exit_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit:
        cli_main(["train", "--env", "nope"])
    assert exit.value.code == 2 and "unknown env 'nope'" in capsys.readouterr().err
    assert cli_main(["train", "--out", str(tmp_path), "--resume"]) == 2  # nothing to resume
    assert "config.json not found" in capsys.readouterr().err


def test_resume_refuses_another_run(tmp_path, reference, capsys):
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    assert cli_main(["train", "--env", "cartpole-mjx", "--out", str(out), "--resume"]) == 2
    assert "env 'cartpole' (given 'cartpole-mjx')" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit:
        cli_main(["train", "--out", str(out), "--resume", "--gamma", "0.9"])
    assert exit.value.code == 2 and "drop --gamma 0.9" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"config.gamma 0.99 \(given 0.9\)"):
        train_run("cartpole", DQNConfig(**{**CONFIG.__dict__, "gamma": 0.9}), seeds=SEEDS, out_dir=out,
                  resume=True, progress=False)


class _FakeTime:
    """`time` for agents.run and agents.run_steps (the save clock): a clock that moves only when told (and 1 us per reading, so no interval
    is zero), so a test fakes slow chunks and saves exactly, without sleeping or depending on load."""

    def __init__(self):
        self.now = 0.0

    def perf_counter(self) -> float:
        self.now += 1e-6
        return self.now


def _faked_saves(monkeypatch, save_s: float, chunk_s: float) -> tuple[list[int], dict]:
    """Make every chunk take `chunk_s` and every save `save_s` on agents.run's clock (saving nothing);
    the chunks each save was called at, and `on_chunk` for train_run."""
    from agents import run, run_steps

    fake_time, saves = _FakeTime(), []

    def slow_save(background_saves, out, env_name, placement, ts, chunks_done, final=False, finished=False,
                  copy_beside=True, clock=None):
        fake_time.now += save_s
        saves.append(chunks_done)

    monkeypatch.setattr(run, "time", fake_time)
    monkeypatch.setattr(run_steps, "time", fake_time)
    monkeypatch.setattr(run, "save", slow_save)
    return saves, {"on_chunk": lambda index, ts, record: setattr(fake_time, "now", fake_time.now + chunk_s)}


@pytest.mark.parametrize("save_s, checkpoint_seconds", [(0.52, 0.001), (0.01, 2.5)], ids=["slow", "fast"])
def test_a_slow_save_spaces_the_next_ones_out(tmp_path, monkeypatch, save_s, checkpoint_seconds):
    """After a save that took D seconds the next periodic one waits max(checkpoint_seconds,
    SAVE_COST_FACTOR x D) (a large sweep's state takes long to write: saving must not take over the
    run); saves faster than checkpoint_seconds / SAVE_COST_FACTOR keep the checkpoint_seconds rhythm."""
    from agents.run_steps import SAVE_COST_FACTOR

    config = DQNConfig(total_steps=3000, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                       eval_episodes=4, hidden=(16,))
    saves, hooks = _faked_saves(monkeypatch, save_s, chunk_s=1.0)
    train_run("cartpole", config, out_dir=tmp_path, progress=False, checkpoint_seconds=checkpoint_seconds, **hooks)
    first = math.ceil(checkpoint_seconds)  # nothing saved yet: checkpoint_seconds alone (1 s chunks)
    gap = math.ceil(max(checkpoint_seconds, SAVE_COST_FACTOR * save_s))  # 11 chunks slow, 3 fast
    periodic = list(range(first, config.num_chunks + 1, gap))
    assert saves == periodic + ([config.num_chunks] if periodic[-1] != config.num_chunks else [])  # + the final save
    assert len(periodic) >= 3


def test_checkpoint_seconds_0_still_saves_every_checkpoint_every_chunks(tmp_path, monkeypatch):
    """However long a save takes (here 100 s)."""
    saves, hooks = _faked_saves(monkeypatch, save_s=100.0, chunk_s=1.0)
    train_run("cartpole", CONFIG, out_dir=tmp_path, progress=False, checkpoint_seconds=0, checkpoint_every=2, **hooks)
    assert saves == [2, 4, 6]


# ---- signals (issue #42): SIGINT and SIGTERM stop a run cleanly, at any moment ---------------------
def _progress(out) -> int:
    try:
        return json.loads((out / checkpoint.PROGRESS_FILE).read_text())["chunks_done"]
    except (FileNotFoundError, ValueError):
        return -1


SIGNAL_MOMENTS = {  # the run's phases, told from its directory (renames slowed by SLOW_SAVES)
    "during compile": lambda out: (out / checkpoint.CONFIG_FILE).is_file(),
    "during training": lambda out: _chunks_logged(out) >= 2,
    "during a save": lambda out: any(out.glob("*.ckpt.tmp")),
    # the last chunk logged: its save is written in the background while the final evaluation runs
    "during the final evaluation": lambda out: _chunks_logged(out) == CONFIG.num_chunks,
}


# Every moment under both signals; by default each moment under one of them, alternating (the
# handler is one function for both: the slow run covers the other half).
SIGNAL_CASES = [pytest.param(moment, signum, id=f"{moment}-{signum.name}",
                             marks=() if (i + (signum == signal.SIGTERM)) % 2 == 0 else pytest.mark.slow)
                for i, moment in enumerate(SIGNAL_MOMENTS) for signum in (signal.SIGINT, signal.SIGTERM)]


@pytest.mark.parametrize("moment, signum", SIGNAL_CASES)
def test_a_signal_stops_the_run_cleanly_and_resume_continues_it(tmp_path, reference, moment, signum):
    """SIGINT or SIGTERM at any moment: the run saves what it has (and says only that), exits with
    128 + the signal's number (or 0 if it had finished), and --resume ends it as the uninterrupted run."""
    out = tmp_path / "run"
    process = start_training(out)
    try:
        wait_for(lambda: SIGNAL_MOMENTS[moment](out), out, process)
    finally:
        process.send_signal(signum)
        status = process.wait(timeout=60)
    said = (out.parent / "stderr.txt").read_text()
    assert "Traceback" not in said and "Error" not in said, said
    if status == 0:  # the final evaluation was over before the signal landed
        assert moment == "during the final evaluation" and (out / "eval.json").is_file()
    else:
        assert status == 128 + signum, said
        assert not (out / "eval.json").exists()
        saved = (out / checkpoint.STATE_FILE).is_file()
        assert saved == (moment != "during compile")
        if saved:
            assert final_state(out)[1] == _progress(out) >= 1  # the stop saved the chunks done
    assert cli_main(["train", "--out", str(out), "--resume"]) == 0
    assert_same_run(out, reference)


def test_what_a_stopped_run_says_is_what_it_saved(tmp_path, capsys, monkeypatch):
    """A signal once the run has written its config (its programs compiling): no checkpoint, and
    the CLI says so (not "saved"); one before the run touched --out: nothing written, and it says so."""
    started = checkpoint.start_run

    def signalled_while_compiling(out, run):
        started(out, run)
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(checkpoint, "start_run", signalled_while_compiling)
    assert cli_main(["train", "--env", "cartpole", "--out", str(tmp_path / "a"), *CONFIG_ARGS]) == 143
    said = capsys.readouterr()
    assert "stopped by SIGTERM before the first checkpoint: nothing trained is saved" in said.out
    assert not (tmp_path / "a" / checkpoint.STATE_FILE).exists()
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # the handlers are put back

    from agents import signals

    entered = signals.StopSignals.__enter__

    def signalled_at_once(self):  # as if the signal came during the command's imports
        entered(self)
        os.kill(os.getpid(), signal.SIGTERM)
        return self

    monkeypatch.setattr(signals.StopSignals, "__enter__", signalled_at_once)
    assert cli_main(["train", "--env", "cartpole", "--out", str(tmp_path / "b"), *CONFIG_ARGS]) == 143
    assert "stopped by SIGTERM before the run started: nothing was written" in capsys.readouterr().out
    assert not (tmp_path / "b" / checkpoint.CONFIG_FILE).exists()


def test_a_signal_during_the_final_evaluation_says_the_run_finishes_and_it_does(tmp_path, monkeypatch, capfd):
    """Case 35: past the signal check before the final evaluation, a first signal stops nothing:
    its message says the run finishes (not "stopping ... and saving"), and the run writes eval.json."""
    from agents import run as run_module

    real = run_module.break_ties

    def signalled(*args, **kwargs):  # inside the final evaluation's tie-break
        os.kill(os.getpid(), signal.SIGINT)
        return real(*args, **kwargs)

    monkeypatch.setattr(run_module, "break_ties", signalled)
    result = run_module.train_run("cartpole", CONFIG, out_dir=tmp_path / "run", progress=False)
    said = capfd.readouterr().err
    assert "SIGINT: the run is past its last checkpoint and finishes its final evaluation and writes eval.json" in said
    assert "stopping" not in said
    assert not result.interrupted and (tmp_path / "run" / "eval.json").is_file()


def test_a_second_signal_exits_at_once(tmp_path):
    code = ("import os, signal, time\nfrom agents.signals import StopSignals\nwith StopSignals() as stop:\n"
            "    os.kill(os.getpid(), signal.SIGINT)\n    assert stop.requested == signal.SIGINT\n"
            "    os.kill(os.getpid(), signal.SIGINT)\n    time.sleep(5)\nprint('not reached')\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 130 and "not reached" not in done.stdout
    assert "SIGINT again: exiting now, without saving" in done.stderr


def test_a_finished_run_is_not_replaced_without_overwrite(tmp_path, reference, capsys):
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert cli_main(["train", "--env", "cartpole", "--out", str(out), *CONFIG_ARGS]) == 2
    assert "holds a run already (dqn on cartpole, finished," in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing lost
    with pytest.raises(ValueError, match="--overwrite"):
        train_run("cartpole", CONFIG, out_dir=out, progress=False)
    assert cli_main(["train", "--env", "cartpole", "--out", str(out), "--overwrite", *CONFIG_ARGS]) == 0


@pytest.mark.parametrize("ranges,message", [
    ("body_mass:pole=-1:2", "body_mass must be positive, and -1:2 reaches -1"),
    ("body_mass:pole=0", "body_mass must be positive, and 0 reaches 0"),
    ("body_mass:pole=x0:2", "body_mass must be positive, and scale factors x0:2 reaches 0"),
    ("geom_friction:pole=-0.1:1", "geom_friction must be non-negative"),
    ("dof_damping:slider=-0.5", "dof_damping must be non-negative"),
])
def test_randomisation_outside_a_fields_domain_is_refused(capsys, ranges, message):
    assert cli_main(["train", "--env", "cartpole-mjx", "--randomize", ranges, *CONFIG_ARGS]) == 2
    err = capsys.readouterr().err
    assert message in err and "keep the low end" in err


def test_the_policy_refuses_non_finite_observations(reference):
    from agents import load_policy

    policy = load_policy(reference)
    assert policy(np.zeros(4)).shape == ()
    with pytest.raises(ValueError, match=r"non-finite observation \(1 NaN or inf values, first in observation 1 of "
                                         r"the batch, at value 2: nan\)"):
        policy(np.array([[0, 0, 0, 0], [0, 0, np.nan, 0]]))
    with pytest.raises(ValueError, match=r"\(1 NaN or inf values, first at value 3: inf\)"):  # one observation (#5)
        policy(np.array([0, 0, 0, np.inf]))


@pytest.mark.parametrize("seed_index", ["1", 1.0, True])
def test_a_seed_index_of_the_wrong_type_is_a_clear_error(reference, seed_index):
    """Case #4: load_policy(DIR, seed_index="1") named the type, not numpy's raw comparison error."""
    from agents import load_policy

    with pytest.raises(TypeError, match=rf"seed_index must be an int .*; got {seed_index!r}"):
        load_policy(reference, seed_index=seed_index)


# ---- portable run directories (issue #42): a run trained with impl="warp" acts anywhere -------------
@pytest.fixture(scope="module")
def warp_run(tmp_path_factory):
    """A cartpole-mjx run as one trained on a GPU with MuJoCo Warp records itself (impl and buffer
    sizes in config.json), trained here with impl="jax", then copied to another folder."""
    out = tmp_path_factory.mktemp("warp") / "trained"
    assert cli_main(["train", "--env", "cartpole-mjx", "--out", str(out), *CONFIG_ARGS]) == 0
    record = json.loads((out / checkpoint.CONFIG_FILE).read_text())
    record["env_options"] = {"impl": "warp", "nconmax": 8, "njmax": 16}
    (out / checkpoint.CONFIG_FILE).write_text(json.dumps(record))
    moved = out.parent / "copied elsewhere"
    shutil.copytree(out, moved)
    shutil.rmtree(out)
    return moved


@pytest.mark.slow  # a faked Warp run's own compiles
@pytest.mark.skipif(jax.default_backend() != "cpu", reason="the fallback is for machines that cannot run Warp")
def test_a_warp_run_gives_its_policy_eval_and_rollout_on_the_cpu(warp_run, tmp_path, capsys):
    from agents import load_policy

    policy = load_policy(warp_run)
    assert "its physics runs with impl='jax' here" in capsys.readouterr().err
    assert policy(np.zeros(4)).shape == ()
    assert cli_main(["eval", "--checkpoint", str(warp_run), "--episodes", "4"]) == 0
    said = capsys.readouterr()
    assert "impl='jax' here" in said.err and json.loads(said.out.splitlines()[-1])["env_options"] == {"impl": "jax"}
    assert cli_main(["eval", "--checkpoint", str(warp_run), "--episodes", "4", "--impl", "jax"]) == 0
    assert "impl='jax' here" not in capsys.readouterr().err  # asked for: no note
    assert cli_main(["rollout", "--checkpoint", str(warp_run), "--rerun", str(tmp_path / "r.rrd")]) == 0
    assert (tmp_path / "r.rrd").stat().st_size > 0
    assert cli_main(["eval", "--checkpoint", str(warp_run), "--impl", "warp"]) == 2  # asked for Warp: refused
    assert "--impl warp" in capsys.readouterr().err


@pytest.mark.parametrize("delay", [0.2, 0.6])
def test_a_signal_while_the_command_starts_exits_cleanly(tmp_path, delay):
    """The `mjxsuite` console script catches signals from its first line: one during the imports
    (JAX, CUDA's plugin) neither raises inside them nor starts training (a KeyboardInterrupt inside
    CUDA's plugin start made JAX fall back to the CPU on a GPU machine)."""
    process = subprocess.Popen([*processes.MJXSUITE, "train", "--env", "cartpole", "--out", str(tmp_path / "run"),
                                *CONFIG_ARGS], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=120)
    assert "Traceback" not in err, err
    assert process.returncode in (0, 130), err  # 0: a fast machine had finished the run
    if "stopping before the run starts" in err:  # caught by the console script: nothing compiled or trained
        assert process.returncode == 130 and not (tmp_path / "run" / checkpoint.STATE_FILE).exists()
        assert "stopped by SIGINT before the run started: nothing was written" in out


def test_the_console_scripts_exit_finishes_every_write_before_it_skips_the_interpreters_teardown(tmp_path):
    """`agents.console.exit_now` (the end of every `mjxsuite` command) ends the process only after
    what the interpreter's own exit would finish: a thread that is not a daemon (the checkpoint
    writer) still writing, the atexit handlers, and output still in stdout's buffer; with the status
    the command returned."""
    code = ("import atexit, pathlib, sys, threading, time\n"
            "from agents.console import exit_now\n"
            "out = pathlib.Path(sys.argv[1])\n"
            "def write():\n"
            "    time.sleep(0.5)\n"
            "    (out / 'thread').write_text('written')\n"
            "threading.Thread(target=write).start()\n"
            "atexit.register(lambda: (out / 'atexit').write_text('ran'))\n"
            "sys.stdout.write('buffered, no newline')\n"
            "exit_now(3)\n")
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=60,
                          check=False)
    assert done.returncode == 3, done.stderr
    assert done.stdout == "buffered, no newline"
    assert (tmp_path / "thread").read_text() == "written" and (tmp_path / "atexit").read_text() == "ran"
