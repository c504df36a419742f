"""PulseWaves reader on the RIEGL file, with checks against its own header, and bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.waveforms.io import read_pulsewaves

NAME = "140823_183115_1_clipped_test"


@pytest.fixture(scope="module")
def pls_path(shared_data):
    return shared_data / "riegl-pulsewaves" / f"{NAME}.pls"


@pytest.fixture(scope="module")
def pw(pls_path):
    return read_pulsewaves(pls_path)


@pytest.mark.realdata
def test_counts(pw):
    assert len(pw) == 4
    out = [s for s in pw.segments if s.kind == "outgoing"]
    ret = [s for s in pw.segments if s.kind == "returning"]
    assert [len(s.samples) for s in out] == [28, 28, 28, 28]
    assert [len(s.samples) for s in ret] == [60, 60]
    assert sorted({s.pulse for s in out}) == [0, 1, 2, 3]
    assert pw.header["system"].startswith("RiPROCESS")
    # the outgoing pulse peaks near 192-194 counts in the middle of its 28 samples
    for s in out:
        assert 180 <= s.samples.max() <= 255 and 8 <= int(np.argmax(s.samples)) <= 14


@pytest.mark.realdata
def test_geometry_matches_header(pw):
    # 1 ns sampling units: the direction vector is c/2 per ns (0.1499 m) long
    np.testing.assert_allclose(np.linalg.norm(pw.direction, axis=1), 0.14990, atol=2e-4)
    # the header's bounding box holds the first and last samples of the returning waves
    h = pw.header
    for s in pw.segments:
        if s.kind != "returning":
            continue
        origin, per_ns = pw.segment_origin(s)
        first = origin
        last = origin + per_ns * s.sample_units_ns * (len(s.samples) - 1)
        for p in (first, last):
            assert h["bbox_min"][0] - 1e-3 <= p[0] <= h["bbox_max"][0] + 1e-3
            assert h["bbox_min"][1] - 1e-3 <= p[1] <= h["bbox_max"][1] + 1e-3
            assert h["bbox_min"][2] - 1e-3 <= p[2] <= h["bbox_max"][2] + 1e-3


@pytest.mark.realdata
def test_missing_wvs(pls_path, tmp_path):
    shutil.copy(pls_path, tmp_path / f"{NAME}.pls")
    with pytest.raises(InputError, match=r"\.wvs.*missing"):
        read_pulsewaves(tmp_path / f"{NAME}.pls")


@pytest.mark.realdata
def test_truncated_wvs(pls_path, tmp_path):
    shutil.copy(pls_path, tmp_path / f"{NAME}.pls")
    data = pls_path.with_suffix(".wvs").read_bytes()
    (tmp_path / f"{NAME}.wvs").write_bytes(data[:-30])
    with pytest.raises(InputError, match="truncated"):
        read_pulsewaves(tmp_path / f"{NAME}.pls")


def test_not_a_pulsewaves_file(tmp_path):
    p = tmp_path / "x.pls"
    p.write_bytes(b"LASF" + bytes(400))
    with pytest.raises(InputError, match="PulseWavesPulse"):
        read_pulsewaves(p)
