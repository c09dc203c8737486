"""The sensor is identified from the data it recorded, or an error lists the candidates."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from forestslam.errors import InputError
from forestslam.io.scan import Scan
from forestslam.sensors import load_profile
from forestslam.sensors.identify import identify

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "cache" / "sample" / "sequence.bag"


def _scans(name, n=3, rings=True, rate_hz=None, seed=0):
    """Scans of a profile's beams on a 12 m wall around the sensor, with a little range noise,
    a fifth of the returns dropped (sky, absorption)."""
    p = load_profile(name)
    rng = np.random.default_rng(seed)
    rate = rate_hz or p.rate_hz
    step = p.azimuth_resolution_deg * p.rate_hz / rate
    out = []
    for k in range(n):
        az = np.radians(np.arange(-p.horizontal_fov_deg / 2, p.horizontal_fov_deg / 2, step))
        el = p.vertical_angles_rad
        A, E = np.meshgrid(az, el)
        ring = np.broadcast_to(np.arange(len(el))[:, None], A.shape).ravel()
        r = 12.0 / np.cos(E.ravel()) + rng.normal(0, 0.02, A.size)
        pts = np.column_stack(
            [
                r * np.cos(E.ravel()) * np.cos(A.ravel()),
                r * np.cos(E.ravel()) * np.sin(A.ravel()),
                r * np.sin(E.ravel()),
            ]
        )
        keep = rng.random(len(pts)) > 0.2
        out.append(Scan(k / rate, pts[keep], ring=ring[keep].astype(np.uint16) if rings else None))
    return out


@pytest.mark.parametrize("name", ["vlp16", "hdl32", "vlp32c", "os1-64", "rs-m1"])
def test_each_shipped_scanner_is_identified_from_its_scans(name):
    assert identify(_scans(name)).name == name


def test_vlp16_at_5_hz_is_still_a_vlp16():
    assert identify(_scans("vlp16", rate_hz=5.0)).name == "vlp16"


def test_without_rings_the_elevations_still_tell():
    assert identify(_scans("hdl32", rings=False)).name == "hdl32"


def test_data_no_profile_fits_lists_the_candidates():
    scans = _scans("vlp16")
    for s in scans:  # a 16-beam sensor with a narrower field: not a shipped one
        s.points[:, 2] *= 0.5
    with pytest.raises(
        InputError, match="no shipped sensor fits.*hdl32: 32 channels.*vlp16: lowest beam"
    ):
        identify(scans)


def test_several_fits_are_ambiguous():
    with pytest.raises(InputError, match="several sensors fit.*vlp16: fits.*Give --sensor"):
        identify(_scans("vlp16"), names=["vlp16", load_profile("vlp16").name])


@pytest.mark.skipif(not SAMPLE.is_file(), reason="bundled sample not simulated (make run)")
def test_simulated_vlp16_recording_is_identified():
    from forestslam.io import read_scans

    stream = read_scans(SAMPLE)
    scans = [next(stream) for _ in range(5)]
    assert identify(scans).name == "vlp16"
