"""Fixtures shared by the rollout tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def restore_threads():
    """Training and evaluation commands set torch's thread count (``--threads``): put it back."""
    n = torch.get_num_threads()
    yield
    torch.set_num_threads(n)
