"""Where a model trains or samples: ``--device cpu|cuda|cuda:N|auto`` of the train and eval commands.

Batches are assembled on the CPU (numpy) and moved to the device; checkpoints are written for the
CPU, so weights trained on a GPU load anywhere. The CPU stays the default: the shipped recipes and
their numbers are the CPU's. What the metrics record about the CPU (:func:`cpu_description`) and
the warning for bfloat16 on a CPU that lacks it (:func:`slow_bf16_warning`) live here too.
"""

from __future__ import annotations

import os
import platform

import torch

from coster_sumo.errors import InputError


def training_device(name: str = "cpu") -> torch.device:
    """The torch device ``name`` names: "cpu", "cuda", "cuda:N", or "auto" (the first GPU when torch
    sees one, else the CPU); an :class:`InputError` line when it is not there."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        dev = torch.device(name)
    except RuntimeError:
        raise InputError(f"--device {name}: not a device (cpu, cuda, cuda:N or auto)") from None
    if dev.type not in ("cpu", "cuda"):
        raise InputError(f"--device {name}: training runs on cpu or cuda")
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"--device {name}: this torch ({torch.__version__}) sees no CUDA GPU")
    return dev


def cpu_bf16_native() -> bool | None:
    """Whether this CPU multiplies bfloat16 in hardware (AVX-512 BF16 or AMX tiles) as torch sees it;
    None when this torch build cannot tell.

    Without them CPU autocast to bfloat16 converts in software around float32 arithmetic: on a
    2-core AMD EPYC with AVX2 only, a rollout training step took 8.6x as long as in float32
    (``bench/RESULTS.md``, "bfloat16 needs a CPU that has it").
    """
    probes = [getattr(torch.cpu, name, None) for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported")]
    known = [probe for probe in probes if callable(probe)]
    if not known:
        return None
    return any(bool(probe()) for probe in known)


def slow_bf16_warning(dev: torch.device, precision: str) -> str | None:
    """One line for a bfloat16 run on a CPU without bfloat16 hardware (it trains, several times
    slower than float32), else None."""
    if precision != "bf16" or dev.type != "cpu" or cpu_bf16_native() is not False:
        return None
    return (f"coster-sumo: warning: --precision bf16 on a CPU without AVX-512 BF16 or AMX (torch sees "
            f"{torch.backends.cpu.get_cpu_capability()}): bfloat16 runs in software here, several times "
            "slower than --precision fp32")


def cpu_description() -> str:
    """What metrics record about the CPU: its model name where the system tells it, the vector
    instructions torch uses and whether bfloat16 is in hardware."""
    name = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    name = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    bf16 = {True: "bf16 in hardware", False: "no bf16 hardware", None: "bf16 unknown"}[cpu_bf16_native()]
    return f"{name}, {os.cpu_count()} cores, {torch.backends.cpu.get_cpu_capability()}, {bf16}"


def device_name(dev: torch.device) -> str:
    """What metrics record about a device: "cpu", or the GPU's name."""
    return torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu"
