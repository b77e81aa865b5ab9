"""What a published figure depends on besides the code and the seed: the CPU's vector
capability and the thread count (issue 25, item 15).

The same run reproduces to the bit on one machine at one thread count, but floating-point sums
are ordered differently by PyTorch's AVX2 and AVX-512 kernels and by different thread counts, so
results move in the last digits, and training amplifies that over many steps.  Every published
number carries :func:`machine_info`; to reproduce a table measured elsewhere, pin the same
capability (``ATEN_CPU_CAPABILITY=avx2``, or ``default`` / ``avx512``, never above what the CPU
has) and thread count (``OMP_NUM_THREADS``) before Python starts (docs/guide/reproducibility.md).
"""

from __future__ import annotations

import os
import platform

import torch

__all__ = ["describe_machine", "machine_info"]


def machine_info() -> dict:
    """``{"cpu_capability", "threads", "aten_cpu_capability_env", "torch", "machine"}``."""
    return {"cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "threads": torch.get_num_threads(),
            "aten_cpu_capability_env": os.environ.get("ATEN_CPU_CAPABILITY"),
            "torch": torch.__version__,
            "machine": platform.machine()}


def describe_machine(info: dict | None = None) -> str:
    """``"CPU capability AVX512, 1 thread(s), torch 2.x"``: the line printed beside figures."""
    info = info or machine_info()
    return (f"CPU capability {info['cpu_capability']}, {info['threads']} thread(s), torch "
            f"{info['torch']}")
