"""benchmarks/device's training scripts, run here on the CPU: a training that outlives the GPU machine's call that
started it goes on in a process session of its own, and a later call collects it (`train.sh`, `wait.sh`)."""

import json
import os
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # a short DQN training in processes of its own
def test_a_training_longer_than_its_call_goes_on_and_a_later_call_collects_it(tmp_path):
    tag = f"test{os.getpid()}"
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}", "TAG": tag, "T": "300",
           "GRACE": "30", "WHEELS": str(tmp_path / "no-wheels")}
    first, second = tmp_path / "first-call", tmp_path / "second-call"
    first.mkdir(), second.mkdir()
    try:
        started = subprocess.run(["bash", "benchmarks/device/train.sh", "--run", "--env cartpole --steps 3000"], cwd=ROOT,
                                 env={**env, "WAIT": "0", "OUT": str(first)}, capture_output=True, text=True, timeout=60)
        assert f"the runs {tag} go on" in started.stdout and not any(first.iterdir()), started.stdout + started.stderr
        # The training outlives its call: the machine ends a call's processes but those of another session.
        for _ in range(100):
            found = subprocess.run(["pgrep", "-f", f"gym_training.*/tmp/runs{tag}"], capture_output=True, text=True)
            if found.stdout:
                break
            time.sleep(0.1)
        assert os.getsid(int(found.stdout)) != os.getsid(0)
        ended = subprocess.run(["bash", "benchmarks/device/wait.sh"], cwd=ROOT, env={**env, "WAIT": "240", "OUT": str(second)},
                               capture_output=True, text=True, timeout=300)
        assert "go on" not in ended.stdout, ended.stdout + ended.stderr
        with tarfile.open(second / f"{tag}.tgz") as archive:
            assert f"runs{tag}/run0/config.json" in archive.getnames()
            [record] = json.load(archive.extractfile(f"runs{tag}/records.json"))
        assert record["command"] == "mjxsuite train --env cartpole --steps 3000" and "interrupted" not in record
    finally:
        shutil.rmtree(f"/tmp/runs{tag}", ignore_errors=True)
