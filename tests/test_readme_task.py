"""The README and the docs pages, run: docs/tasks.md's "Writing a task" example literally (its
files written to a fresh directory and its commands run there, as a user would), every
```` ```python run ```` block of every page, every `mjxsuite` command line parsed by the real
command-line parser, every `make` target, every link and repository path they name, and the
README's length."""

import importlib.util
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from test_recording import Contents

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
TASKS = ROOT / "docs" / "tasks.md"
README_MOST_BYTES = 8_000  # as `wc -c` counts them: the front door; details go to docs/
PAGES = [README, ROOT / "ARCHITECTURE.md", *sorted((ROOT / "docs").glob("*.md"))]


def page_section(page: Path, title: str) -> str:
    text = page.read_text()
    start = text.index(f"## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end != -1 else None]


def code_blocks(section: str) -> list[tuple[str, str]]:
    """(info string, body) of every fenced block."""
    return re.findall(r"^```([^\n]*)\n(.*?)^```", section, flags=re.S | re.M)


@pytest.mark.slow
def test_the_writing_a_task_example_works_as_written(tmp_path):
    blocks = code_blocks(page_section(TASKS, "Writing a task"))
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


def page_blocks(language: str) -> list[tuple[Path, str, str]]:
    """(page, info string, body) of every fenced block of that language on every page."""
    return [(page, info, body) for page in PAGES for info, body in code_blocks(page.read_text())
            if info.split(" ")[0] == language]


# ```python run``` blocks; ```python run slow``` ones run with the slow tests (`make test-slow`).
RUN_BLOCKS = [pytest.param(page, body, id=f"{page.relative_to(ROOT)}:{i}",
                           marks=[pytest.mark.slow] if info.split()[2:3] == ["slow"] else [])
              for i, (page, info, body) in enumerate(block for block in page_blocks("python")
                                                      if block[1].split()[1:2] == ["run"])]


@pytest.mark.parametrize("page,body", RUN_BLOCKS)
def test_python_blocks_marked_run_run(tmp_path, page, body):
    (tmp_path / "example.py").write_text(body)
    done = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{page.relative_to(ROOT)}:\n{body}\n{done.stderr[-3000:]}"


def command_lines(program: str) -> list[tuple[Path, str]]:
    """Lines of bash blocks that run `program`, without their trailing comments."""
    lines = []
    for page, _, body in page_blocks("bash"):
        for line in body.splitlines():
            words = shlex.split(line, comments=True)
            if words[:1] == [program]:
                lines.append((page, shlex.join(words)))
    return lines


def test_every_documented_mjxsuite_command_line_parses():
    """Subcommand, options and config fields are all accepted (nothing runs)."""
    from agents import registry
    from agents.cli import config_fields, config_from_args
    from benchmarks.cli import build_parser

    commands = command_lines("mjxsuite")
    assert len(commands) >= 15 and {"train", "eval", "rollout", "bench"} <= {c.split()[1] for _, c in commands}
    parser = build_parser()
    for page, command in commands:
        where = f"{page.relative_to(ROOT)}: {command}"
        try:
            args = parser.parse_args(shlex.split(command)[1:])
            if args.command == "train":
                config_from_args(registry.config_class(args.agent or "dqn")(), config_fields(args))
        except SystemExit as err:  # argparse's and config_from_args's way to refuse
            pytest.fail(f"{where}: refused ({err})")


def test_every_documented_make_target_and_module_exists():
    targets = set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), flags=re.M))
    makes = command_lines("make")
    assert makes and all(c.split()[1] in targets for _, c in makes), makes
    for page, command in command_lines("python"):
        words = command.split()
        if words[1] == "-m":
            assert importlib.util.find_spec(words[2]), f"{page.relative_to(ROOT)}: {command}"


def anchors(page: Path) -> set[str]:
    """GitHub's anchors for the page's headings."""
    headings = re.findall(r"^#+ (.+)$", re.sub(r"^```.*?^```", "", page.read_text(), flags=re.S | re.M), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-") for h in headings}


def test_every_link_and_repository_path_on_the_pages_exists():
    """Relative links (and their #anchors), and `envs/...`-style paths in code spans, name
    files and headings that exist."""
    missing = []
    for page in PAGES:
        text = page.read_text()
        for target, anchor in re.findall(r"\]\(([^)#\s]*)(?:#([^)]*))?\)", text):
            if re.match(r"\w+://", target):
                continue
            linked = page.parent / target if target else page
            if not linked.exists():
                missing.append(f"{page.relative_to(ROOT)}: link {target}")
            elif anchor and anchor not in anchors(linked):
                missing.append(f"{page.relative_to(ROOT)}: link {target}#{anchor}")
        for path in re.findall(r"`((?:envs|agents|benchmarks|tests|assets|docs)/[\w./-]*)`", text):
            if not (ROOT / path).exists():
                missing.append(f"{page.relative_to(ROOT)}: path {path}")
    assert not missing, "\n".join(missing)


def test_the_readme_stays_short():
    assert len(README.read_bytes()) <= README_MOST_BYTES, "move details to a page in docs/"
