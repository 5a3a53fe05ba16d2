"""Benchmark harness: warm up, synchronize, repeat to a time budget, report throughput.

Each benchmark builds its inputs once, then times closures that launch work and wait
for it (the closure itself synchronizes, so queued device work is never missed).
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass, field
from typing import Callable


@dataclass
class Row:
    case: str
    impl: str
    seconds: float  # best time per call
    elements: float  # work items per call (e.g. candidate x dimension x query)
    nbytes: float  # bytes of candidate data read per call
    peer: bool  # a peer (not geosynth)
    note: str = ""
    extra: dict = field(default_factory=dict)


def time_call(fn: Callable[[], object], min_time: float = 0.1, max_repeats: int = 50, warmup: int = 1) -> float:
    """Best wall time of ``fn()`` in seconds: warm-up calls first, then repeats until
    ``min_time`` has passed (at least 2 calls, at most ``max_repeats``)."""
    for _ in range(warmup):
        fn()
    best, spent, count = float("inf"), 0.0, 0
    while count < 2 or (spent < min_time and count < max_repeats):
        t0 = time.perf_counter()
        fn()
        dt = time.perf_counter() - t0
        best, spent, count = min(best, dt), spent + dt, count + 1
    return best


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}, Python {platform.python_version()}"


def table(rows: list[Row]) -> str:
    """A Markdown table per case: time, throughput, GB/s, ratio to the fastest peer."""
    out = []
    cases = list(dict.fromkeys(r.case for r in rows))
    out.append("| case | implementation | time/call | elements/s | GB/s | vs fastest peer | note |")
    out.append("|---|---|---:|---:|---:|---:|---|")
    for case in cases:
        group = [r for r in rows if r.case == case]
        peers = [r.seconds for r in group if r.peer]
        fastest = min(peers) if peers else None
        for r in group:
            ratio = f"{fastest / r.seconds:.2f}x" if fastest else "-"
            t = f"{r.seconds * 1e3:.2f} ms" if r.seconds < 10 else f"{r.seconds:.1f} s"
            out.append(
                f"| {case} | {r.impl} | {t} | {r.elements / r.seconds:.3g} | {r.nbytes / r.seconds / 1e9:.2f} | {ratio} | {r.note} |"
            )
    out.append("")
    out.append("'vs fastest peer' is the fastest peer's time divided by this row's: above 1.00x is faster than every peer.")
    return "\n".join(out)
