"""The README's "Add your own task" section, run literally: its files are written to a
fresh directory and its commands run there, as a user would, touching no suite internals."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

from test_recording import Contents

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_section(title: str) -> str:
    text = README.read_text()
    start = text.index(f"## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end != -1 else None]


def code_blocks(section: str) -> list[tuple[str, str]]:
    """(info string, body) of every fenced block."""
    return re.findall(r"^```([^\n]*)\n(.*?)^```", section, flags=re.S | re.M)


def test_add_your_own_task_section_works_as_written(tmp_path):
    blocks = code_blocks(readme_section("Add your own task"))
    files = {info.split("file=")[1]: body for info, body in blocks if "file=" in info}
    commands = [line for info, body in blocks if info == "bash run" for line in body.splitlines() if line.strip()]
    assert {"my_tasks/puck.xml", "my_tasks/puck.py", "check_puck.py"} <= set(files) and len(commands) == 3
    for name, body in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(body)

    bin_dir = str(Path(sys.executable).parent)  # where `pip install` put the `mjxsuite` script
    environment = {**os.environ, "PATH": bin_dir + os.pathsep + os.environ["PATH"]}
    outputs = []
    for command in commands:
        if command.startswith("python "):
            command = f"{sys.executable} {command[len('python '):]}"
        done = subprocess.run(command, shell=True, cwd=tmp_path, env=environment, capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0, f"{command}\n{done.stdout}\n{done.stderr}"
        outputs.append(done.stdout)

    assert "(8, 2) (8,)" in outputs[0]  # the jit/vmap check prints the batch shapes
    result = json.loads((tmp_path / "runs/puck/eval.json").read_text())
    assert result["env"] == "puck" and result["mean_return"][0] > 60  # a random policy scores about 20
    contents = Contents(tmp_path / "puck.rrd")
    assert {"world/env_0/puck", "world/env_3/goal", "env/0/reward", "env/0/obs/obs_0"} <= contents.entities
    assert contents.rows["env/0/reward"] == contents.rows["world/env_0/puck"] > 0
