"""Shared fixtures of the Python tests: a scratch directory and the disk scene built in numpy.

The disk: radius 1 at height 1 facing down, tiled by surfels on a square grid whose areas equal
the grid cells'. A receiver on its axis at distance h, facing it, sees the form factor
r^2 / (h^2 + r^2) (the occlusion), and with the disk's radiance L the irradiance pi L times it.
"""
import os
import pathlib
import tempfile

import numpy as np
import pytest

import pbgi

DISK_RADIUS = 1.0
DISK_HEIGHT = 1.0
DISK_RADIANCE = np.array([0.5, 0.25, 1.0])


def disk_surfels(pitch=0.01, radius=DISK_RADIUS, height=DISK_HEIGHT):
    """positions (n, 3), normals (n, 3), radii (n,), radiance (n, 3) as float64."""
    k = int(np.ceil(radius / pitch))
    u = (np.arange(-k, k) + 0.5) * pitch
    uu, vv = np.meshgrid(u, u)
    inside = uu**2 + vv**2 <= radius**2
    n = int(inside.sum())
    positions = np.stack([uu[inside], vv[inside], np.full(n, height)], axis=1)
    normals = np.tile([0.0, 0.0, -1.0], (n, 1))
    radii = np.full(n, pitch / np.sqrt(np.pi))
    radiance = np.tile(DISK_RADIANCE, (n, 1))
    return positions, normals, radii, radiance


def form_factor(r, h):
    return r * r / (h * h + r * r)


def axis_receivers(count, height=DISK_HEIGHT):
    """Receivers on the disk's axis, 0.25 to 1.75 below it, facing up."""
    h = 0.25 + 1.5 * (np.arange(count) % 16) / 15.0
    positions = np.stack([np.zeros(count), np.zeros(count), height - h], axis=1)
    normals = np.tile([0.0, 0.0, 1.0], (count, 1))
    return positions, normals, h


@pytest.fixture(scope="session")
def scratch():
    root = os.environ.get("PBGI_TEST_TMPDIR")
    if root:
        os.makedirs(root, exist_ok=True)
    d = tempfile.mkdtemp(prefix="pbgi-python-", dir=root or None)
    return pathlib.Path(d)


@pytest.fixture(scope="session")
def disk_db(scratch):
    """A radiance database of the disk, and its surfels."""
    p, n, r, c = disk_surfels()
    path = scratch / "disk.pbgi"
    stats = pbgi.build(path, p, n, r, c, leaf_size=8, page_size=4096 - 16, memory="64M")
    return path, (p, n, r, c), stats
