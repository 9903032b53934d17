"""Where a program's GPU time goes: `jax.profiler` traces, summed by kernel.

`traced(dir)` is `jax.profiler.trace(dir, create_perfetto_trace=True)`; `summary(dir)` reads the
Perfetto trace it wrote and sums the device's kernel events by name: kernel seconds, launches, the
span from the first kernel's start to the last one's end (so `busy` = kernel seconds / span shows
how much of the span the GPU idled, waiting on the host or on launches), and the top kernels.
"""

from __future__ import annotations

import collections
import gzip
import json
from pathlib import Path


def traced(directory: str | Path):
    import jax

    return jax.profiler.trace(str(directory), create_perfetto_trace=True)


def summary(directory: str | Path, top: int = 12) -> dict:
    files = sorted(Path(directory).rglob("*.trace.json.gz"))
    if not files:
        return {"error": f"no Perfetto trace under {directory}"}
    events = json.loads(gzip.decompress(files[-1].read_bytes()))
    events = events["traceEvents"] if isinstance(events, dict) else events
    device_pids = {e["pid"] for e in events if e.get("ph") == "M" and e.get("name") == "process_name"
                   and "GPU" in str(e.get("args", {}).get("name", ""))}
    kernels = [e for e in events if e.get("ph") == "X" and e.get("pid") in device_pids and "dur" in e]
    if not kernels:
        return {"error": "no device events in the trace", "processes": len(device_pids)}
    by_name = collections.defaultdict(lambda: [0.0, 0])
    for e in kernels:
        by_name[e["name"]][0] += e["dur"] * 1e-6
        by_name[e["name"]][1] += 1
    busy = sum(s for s, _ in by_name.values())
    span = (max(e["ts"] + e["dur"] for e in kernels) - min(e["ts"] for e in kernels)) * 1e-6
    ranked = sorted(by_name.items(), key=lambda kv: -kv[1][0])[:top]
    return {"kernel_s": round(busy, 4), "launches": len(kernels), "span_s": round(span, 4),
            "busy": round(busy / span, 3) if span else None,
            "top": [{"name": name[:80], "s": round(s, 4), "count": n} for name, (s, n) in ranked]}


def kernels_of(runs: dict, directory: str | Path) -> dict:
    """One more call of each `runs[name]()` (a compiled program, its inputs bound) under
    `jax.profiler`, traced to directory/name, its device time summed by kernel (`summary`)."""
    import jax

    summaries = {}
    for name, run in runs.items():
        with traced(Path(directory) / name):
            jax.block_until_ready(run())
        summaries[name] = summary(Path(directory) / name)
    return {"kernels": summaries, "trace_dir": str(directory)}
