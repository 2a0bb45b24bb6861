"""Shared pytest fixtures: one ``device`` fixture over ``cpu`` and ``cuda:0`` when present."""

import numpy as np
import pytest
import warp as wp

wp.config.log_level = wp.LOG_WARNING
wp.init()

DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


@pytest.fixture(params=DEVICES)
def device(request):
    """Warp device name every kernel test runs on: ``cpu`` always, ``cuda:0`` when available."""
    return request.param


@pytest.fixture
def rng():
    """Seeded numpy generator so every test is reproducible."""
    return np.random.default_rng(12345)
