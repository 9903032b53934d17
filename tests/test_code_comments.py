"""Comments in the library state decisions; the measurements behind them live in the records.

A comment or docstring in `envs/` or `agents/` that quotes a machine, a date or a timing goes
stale the day the code, JAX or the hardware changes, and nobody reruns it. The figure belongs in
docs/bench-*.json (a record of its `kind`) or on a docs page, and the comment names where. A few
lines may keep a figure where the figure is the reason (at most `MAX_MEASUREMENT_LINES`).
"""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_MEASUREMENT_LINES = 5

MEASUREMENT = re.compile(
    r"\b[HAV]100s?\b|\bH200s?\b|\bRTX ?\d"                       # a machine
    r"|\b\d+[- ]core\b|\b\d+ (CPU )?cores\b"
    r"|\b20\d\d-\d\d-\d\d\b"                                       # a date
    r"|\d(\.\d+)? ?(ms|µs|us)\b"                                   # a timing
    r"|env-steps/s\b|steps/s\b"                                    # a throughput
    r"|\d[\d.]*x (faster|slower|the)\b|\d[\d.]*% (faster|slower|more|less|longer|shorter)\b|~\d[\d.]*% of a\b"
)
# Seconds are a timing unless the line speaks of simulated time (a task's dt, an episode's length).
SECONDS = re.compile(r"\d[\d.,]*\+? ?(s|seconds|min|minutes)\b")
SIMULATED_TIME = re.compile(r"\b(dt|timestep|simulated)\b")


def quotes_a_measurement(line: str) -> bool:
    return bool(MEASUREMENT.search(line) or (SECONDS.search(line) and not SIMULATED_TIME.search(line)))


def measurement_lines() -> list[str]:
    found = []
    for path in sorted(p for package in ("envs", "agents") for p in (ROOT / package).rglob("*.py")):
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if quotes_a_measurement(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    return found


def test_few_lines_of_the_library_quote_machines_dates_or_timings():
    found = measurement_lines()
    assert len(found) <= MAX_MEASUREMENT_LINES, (
        f"{len(found)} lines quote a machine, a date or a timing (at most {MAX_MEASUREMENT_LINES}): state the "
        "decision and name the record in docs/bench-*.json (its kind) or the docs page instead:\n" + "\n".join(found))


def test_the_pattern_sees_each_kind_of_measurement():
    for line in ("ran 26% slower on an H200", "21.2 against 25.6 ms a chunk", "(0.55-0.94 s against 0.35 s)",
                 "measured 2026-11-26", "gave 19.1M env-steps/s", "1.06x faster", "on a 2-core CPU", "took 33 us",
                 "about 2.5 s", "compiles in 5 seconds", "~4% of a training step"):
        assert quotes_a_measurement(line), line
    for line in ("frame skip 5 (dt 0.05 s)", "max_speed: float = 8.0  # rad/s", "at most 5% of a run",
                 "timestep 0.003 s", "x_dot, theta"):
        assert not quotes_a_measurement(line), line
