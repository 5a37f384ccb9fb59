"""Which CPU a result was made on: the model and the instruction sets that change numerics.

On one machine every episode repeats exactly. On another CPU the expert repeats almost all of them (two long dense
routes of benchmark v3 took other paths), while a network's outputs differ in the last bits (kernels picked per
instruction set: AVX2 or AVX-512, VNNI, BF16, AMX) and in closed loop those bits grow into other trajectories.
Results that pair episodes record the machine they ran on; benchmark records also record when (`utc_stamp`).
"""

from __future__ import annotations

import os
import platform
from datetime import datetime, timezone
from pathlib import Path

# flags of /proc/cpuinfo that select other inference kernels (OpenVINO, oneDNN, PyTorch)
NUMERIC_FLAGS = ("avx2", "fma", "avx512f", "avx512bw", "avx512_vnni", "avx_vnni", "avx512_bf16", "amx_tile",
                 "amx_int8", "amx_bf16", "avx512_fp16")


def cpu_model(cpuinfo: str | None = None) -> tuple[str, str]:
    """(model name, its numeric flags of NUMERIC_FLAGS, space-separated) from /proc/cpuinfo (on systems without it: the
    platform's name, "no listed flags")."""
    if cpuinfo is None:
        path = Path("/proc/cpuinfo")
        cpuinfo = path.read_text(errors="replace") if path.exists() else ""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    model = fields.get("model name") or platform.processor() or platform.machine()
    flags = set(fields.get("flags", "").split())
    return model, " ".join(flag for flag in NUMERIC_FLAGS if flag in flags) or "no listed flags"


def describe_cpu(cpuinfo: str | None = None) -> str:
    """'<model name>, <n> CPUs, <numeric flags>'."""
    model, numeric = cpu_model(cpuinfo)
    return f"{model}, {os.cpu_count()} CPUs, {numeric}"


def utc_stamp(now: datetime | None = None) -> str:
    """'YYYY-MM-DD HH:MM UTC': when a benchmark result was measured (its record's 'date', 'measured_at' or
    'started_utc')."""
    return f"{(now or datetime.now(timezone.utc)).astimezone(timezone.utc):%Y-%m-%d %H:%M} UTC"
