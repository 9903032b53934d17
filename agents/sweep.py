"""`mjxsuite sweep`'s results, summarised per config. Agent `c * seeds + s` of the one program is
config `c` of the grid (`agents.registry.sweep_configs`) with the key seed `s` of `mjxsuite train`
gets, so it ends as that run's seed `s` does (tests/test_sharding.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from agents.registry import sweep_configs

SUMMARY_FILE = "sweep.json"
PLOT_FILE = "sweep.png"


def summarize(env: str, config: Any, grid: dict[str, list[float]], seeds: int, result) -> dict:
    """One record per config: its swept values; per seed the final return of its best parameters, the
    best evaluation in training and the solve step (None: never); the medians and spreads over seeds."""
    records = []
    best = result.history[-1]["best_return"] if result.history else [math.nan] * len(result.mean_return)
    for c, member in enumerate(sweep_configs(config, grid)):
        agents = slice(c * seeds, (c + 1) * seeds)
        returns = result.mean_return[agents]
        solves = result.solve_step[agents]
        steps = [s for s in solves if s is not None]
        records.append({
            **{name: getattr(member, name) for name in grid},
            "mean_return": returns, "best_return": list(np.atleast_1d(best)[agents].tolist()),
            "solve_step": solves, "solve_rate": len(steps) / seeds, "median_return": float(np.median(returns)),
            "return_quartiles": [float(q) for q in np.percentile(returns, [25, 75])],
            # Unsolved seeds count as never: no median while half or more of them never solved.
            "median_solve_step": float(np.median(steps + [math.inf] * (seeds - len(steps))))
            if 2 * len(steps) > seeds else None})
    return {"env": env, "seeds": seeds, "swept": list(grid), "configs": records, "wall_s": result.wall_s,
            "compile_s": result.compile_s, "devices": result.devices,
            "solve_return": config.solve_return, "total_steps": config.total_steps}


def write_summary(out: Path, summary: dict) -> Path:
    path = Path(out) / SUMMARY_FILE
    path.write_text(json.dumps(summary, indent=2))
    return path


def markdown_table(summary: dict) -> str:
    """One row per config: its values, seeds solved, median return (quartiles), median steps to solve."""
    swept = summary["swept"]
    lines = ["| " + " | ".join(swept + ["solved", "median return (IQR)", "median steps to solve"]) + " |",
             "|" + "---|" * len(swept) + "---:|---:|---:|"]
    for record in summary["configs"]:
        low, high = record["return_quartiles"]
        steps = record["median_solve_step"]
        cells = [f"{record[name]:g}" for name in swept] + [
            f"{round(record['solve_rate'] * summary['seeds'])}/{summary['seeds']}",
            f"{record['median_return']:.1f} ({low:.1f}-{high:.1f})",
            "never" if steps is None else f"{steps:.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(summary: dict, path: str | Path) -> Path | None:
    """Solve rate and median steps to solve per config, as a PNG; None without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    records, swept = summary["configs"], summary["swept"]
    labels = [", ".join(f"{name}={r[name]:g}" for name in swept) for r in records]
    positions = np.arange(len(records))
    figure, (rate, steps) = plt.subplots(2, 1, sharex=True, figsize=(max(6.0, 0.5 * len(records) + 2), 6))
    rate.bar(positions, [r["solve_rate"] for r in records], color="tab:blue")
    rate.set_ylabel(f"solve rate ({summary['seeds']} seeds)")
    rate.set_ylim(0, 1.05)
    medians = [r["median_solve_step"] for r in records]
    steps.bar(positions, [m if m is not None else 0 for m in medians], color="tab:orange")
    for x, m in zip(positions, medians):
        if m is None:
            steps.text(x, 0, "never", ha="center", va="bottom", rotation=90, fontsize=8)
    steps.set_ylabel("median env steps to solve")
    steps.set_ylim(bottom=0)
    steps.set_xticks(positions, labels, rotation=60, ha="right", fontsize=8)
    rate.set_title(f"{summary['env']}: {len(records)} configs x {summary['seeds']} seeds "
                   + ("" if summary["solve_return"] is None else f"(solved: return >= {summary['solve_return']:g})"))
    figure.tight_layout()
    path = Path(path)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def agent_paths(config: Any, grid: dict[str, list[float]], seeds: int) -> tuple[list[str], list[str]]:
    """Rerun entity paths and series labels of every agent of a sweep: `config_<c>/seed_<s>`."""
    values = [", ".join(f"{name}={getattr(member, name):g}" for name in grid) for member in sweep_configs(config, grid)]
    return ([f"config_{c}/seed_{s}" for c in range(len(values)) for s in range(seeds)],
            [f"{config_values}, seed {s}" for config_values in values for s in range(seeds)])
