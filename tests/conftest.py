"""Shared fixtures."""
import pytest


@pytest.fixture
def one_torch_thread():
    """torch on one thread for the test: CPU training is then bit-reproducible (with two
    threads, reductions may add in another order and runs differ by ~1e-5 after 20 steps)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
