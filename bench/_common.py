"""Helpers shared by the benchmark scripts (run as ``.venv/bin/python bench/NAME.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def load1() -> float:
    """The 1-minute load average, recorded beside every figure."""
    return float(Path("/proc/loadavg").read_text().split()[0])


def cpu_model() -> str:
    """The machine's processor (``model name`` of /proc/cpuinfo), recorded beside figures
    that differ by machine."""
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown"


def service_bump(mesh, i: int, r: float = 0.1) -> np.ndarray:
    """The service's bump ``{"vertex": i, "radius": r}``: masses ``a_j max(0, 1 - |x_j - x_i| /
    r)`` (unit-area coordinates), normalized."""
    d = np.linalg.norm(mesh.vertices - mesh.vertices[i], axis=1)
    m = mesh.areas * np.clip(1 - d / r, 0, None)
    return m / m.sum()
