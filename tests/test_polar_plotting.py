"""Polar -> Cartesian resampling and the RA figure writers."""
from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest

from helpers import peak_index
from sionna_mmir.errors import InputValueError
from sionna_mmir.plotting import plot_range_azimuth, save_ra_panels
from sionna_mmir.processing import polar_to_cartesian

DEG = math.pi / 180.0
RANGES = np.arange(200) * 0.05                              # 0 .. 9.95 m
AZ = np.arcsin(np.linspace(-0.95, 0.95, 96))                # increasing, non-uniform


def _blob(r0, az0):
    """Smooth bump centred exactly on grid point (r0, az0)."""
    rr, aa = np.meshgrid(RANGES, AZ, indexing="ij")
    return np.exp(-((rr - r0) / 0.1) ** 2 - ((aa - az0) / (2 * DEG)) ** 2)


def _png_size(path):
    with open(path, "rb") as fh:
        head = fh.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


def test_01_point_lands_at_its_xy():
    for i, j in ((120, 30), (60, 70), (150, 48)):
        r0, az0 = RANGES[i], AZ[j]
        img, x, y = polar_to_cartesian(_blob(r0, az0), RANGES, AZ)
        assert img.shape == (y.size, x.size)
        dx, dy = x[1] - x[0], y[1] - y[0]
        assert math.isclose(dx, 0.05) and math.isclose(dy, 0.05)   # default: range bin
        iy, ix = peak_index(img)
        # x forward = r cos az, y left = r sin az
        assert abs(x[ix] - r0 * math.cos(az0)) <= dx
        assert abs(y[iy] - r0 * math.sin(az0)) <= dy


def test_02_field_of_view_and_resolution():
    ones = np.ones((RANGES.size, AZ.size))
    img, x, y = polar_to_cartesian(ones, RANGES, AZ, x_res=0.1, y_res=0.2, max_range=8.0)
    assert math.isclose(x[1] - x[0], 0.1) and math.isclose(y[1] - y[0], 0.2)
    assert x[0] == 0.0 and x[-1] <= 8.0 and np.all(np.diff(y) > 0)
    xx, yy = np.meshgrid(x, y)
    rr, aa = np.hypot(xx, yy), np.arctan2(yy, xx)
    inside = (rr <= 8.0) & (aa >= AZ[0]) & (aa <= AZ[-1])
    assert np.allclose(img[inside], 1.0)
    assert np.all(img[~inside] == 0.0)
    # beyond the largest azimuth (asin 0.95 = 71.8 deg) and beyond max_range: zero
    assert img[np.argmin(np.abs(y - 3.0)), np.argmin(np.abs(x - 0.5))] == 0.0
    with pytest.raises(InputValueError, match="n_range"):
        polar_to_cartesian(ones[:, :-1], RANGES, AZ)


def test_03_save_panels_png(tmp_path):
    ra = _blob(5.0, AZ[40]) + 1e-3
    path = tmp_path / "sub" / "panels.png"
    out = save_ra_panels({"measured": ra, "mmIR": ra ** 2, "Sionna RT": 0.5 * ra},
                         RANGES, AZ, path, panel_size=(3.0, 2.5), dpi=80)
    assert os.fspath(path) == out
    assert path.stat().st_size > 1000
    assert _png_size(path) == (round((3 * 3.0 + 1) * 80), round(2.5 * 80))      # 800 x 200
    assert os.listdir(path.parent) == ["panels.png"]                # no temp files left
    path2 = tmp_path / "polar.png"
    save_ra_panels({"a": ra, "b": ra}, RANGES, AZ, path2, cartesian=False, db=False,
                   normalize_each=False, dpi=50)
    assert _png_size(path2) == ((4 * 2 + 1) * 50, 4 * 50)
    with pytest.raises(InputValueError):
        save_ra_panels({}, RANGES, AZ, tmp_path / "x.png")


def test_04_plot_range_azimuth_axes():
    ra = _blob(4.0, 0.0)
    ax = plot_range_azimuth(ra, RANGES, AZ, title="one")
    assert ax.get_title() == "one" and "range" in ax.get_ylabel()
    ax2 = plot_range_azimuth(ra, RANGES, AZ, cartesian=True, db=False)
    assert "forward" in ax2.get_ylabel() and "left" in ax2.get_xlabel()
    with pytest.raises(InputValueError, match="complex"):
        plot_range_azimuth(ra.astype(complex), RANGES, AZ)
