"""Where a model trains or samples: ``--device cpu|cuda|cuda:N|auto`` of the train and eval commands.

Batches are assembled on the CPU (numpy) and moved to the device; checkpoints are written for the
CPU, so weights trained on a GPU load anywhere. The CPU stays the default: the shipped recipes and
their numbers are the CPU's.
"""

from __future__ import annotations

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


def device_name(dev: torch.device) -> str:
    """What metrics record about a device: "cpu", or the GPU's name."""
    return torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu"
