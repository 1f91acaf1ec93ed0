"""Shared by the benchmark scripts: record figures in RESULTS.md and results/<name>.json."""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def machine() -> str:
    """One line about this machine: CPU model, core count, Python."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"


def record(name: str, title: str, figures: dict[str, float], notes: str = "") -> None:
    """Print the figures, write ``results/<name>.json`` (flat keys, SI units in the key names)
    and append a section to ``RESULTS.md`` with the command, the date and the machine."""
    for key, value in figures.items():
        print(f"{key:>45s}  {value:.6g}")
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / f"{name}.json").write_text(json.dumps(figures, indent=2) + "\n")
    command = "python " + " ".join([Path(sys.argv[0]).as_posix(), *sys.argv[1:]])
    lines = [
        f"## {title}",
        "",
        f"- command: `{command}`",
        f"- date: {dt.datetime.now().isoformat(timespec='seconds')}",
        f"- machine: {machine()}",
        "",
        "| figure | value |",
        "|---|---|",
        *[f"| {k} | {v:.6g} |" for k, v in figures.items()],
        "",
    ]
    if notes:
        lines += [notes, ""]
    results = HERE / "RESULTS.md"
    if not results.exists():
        results.write_text("# Benchmark results\n\nAppended by the scripts in this folder.\n\n")
    with results.open("a") as fh:
        fh.write("\n".join(lines) + "\n")
