"""Bad input is refused clearly (argument, expected and actual shape or dtype, first bad index),
and the library's errors arrive as pbgi.Error subclasses with its message and absl code."""
import os

import numpy as np
import pytest

import pbgi
from conftest import axis_receivers, disk_surfels


@pytest.fixture(scope="module")
def db(disk_db):
    return pbgi.open(disk_db[0])


def test_exception_hierarchy():
    assert issubclass(pbgi.InvalidArgumentError, pbgi.Error)
    assert issubclass(pbgi.InvalidArgumentError, ValueError)
    for name, code in [("CancelledError", 1), ("NotFoundError", 5), ("DataLossError", 15),
                       ("FailedPreconditionError", 9), ("ResourceExhaustedError", 8)]:
        cls = getattr(pbgi, name)
        assert issubclass(cls, pbgi.Error) and cls.code == code


@pytest.mark.parametrize("bad, pattern", [
    (np.zeros((4, 2)), r"positions: expected shape \(n, 3\), got \(4, 2\)"),
    (np.zeros(12), r"positions: expected shape \(n, 3\), got \(12,\)"),
    (np.zeros((4, 3, 1)), r"positions: expected shape \(n, 3\), got \(4, 3, 1\)"),
    (np.zeros((4, 3), dtype=np.int64), r"positions: expected dtype float32 or float64, got int64"),
    (np.zeros((4, 3), dtype=np.float16), r"positions: expected dtype float32 or float64, got float16"),
    (np.zeros((4, 3), dtype=">f8"), r"positions: expected dtype float32 or float64, got >f8"),
    ("not an array", r"positions: expected a numpy array, got str"),
])
def test_shade_refuses_bad_positions(db, bad, pattern):
    normals = np.tile([0.0, 0.0, 1.0], (4, 1))
    with pytest.raises(pbgi.InvalidArgumentError, match=pattern) as e:
        db.shade(bad, normals)
    assert e.value.code == 3 and e.value.code_name == "INVALID_ARGUMENT"


def test_shade_refuses_mismatched_lengths(db):
    p, n, _ = axis_receivers(8)
    with pytest.raises(ValueError, match=r"normals: expected shape \(8, 3\) like positions, got \(7, 3\)"):
        db.shade(p, n[:7])
    with pytest.raises(ValueError, match=r"reflections: expected shape \(8, 3\), got \(8, 2\)"):
        db.shade(p, n, n[:, :2], mode="glossy")


def test_shade_names_the_first_bad_receiver(db):
    p, n, _ = axis_receivers(8)
    bad = p.copy()
    bad[5, 1] = np.nan
    bad[6, 0] = np.inf
    with pytest.raises(pbgi.InvalidArgumentError, match=r"positions\[5\] is not finite") as e:
        db.shade(bad, n)
    assert "nan" in str(e.value)
    zero = n.copy()
    zero[3] = 0.0
    with pytest.raises(pbgi.InvalidArgumentError, match=r"normals\[3\] is zero"):
        db.shade(p, zero)
    big = n.copy()
    big[2, 2] = 1e300  # finite in float64, not in float32
    with pytest.raises(pbgi.InvalidArgumentError, match=r"normals\[2\] is not finite \(as float32\)"):
        db.shade(p, big)


def test_shade_refuses_bad_options(db):
    p, n, _ = axis_receivers(4)
    with pytest.raises(pbgi.InvalidArgumentError, match="resolution"):
        db.shade(p, n, resolution=2)
    with pytest.raises(pbgi.InvalidArgumentError, match="mode"):
        db.shade(p, n, mode="shiny")
    with pytest.raises(pbgi.InvalidArgumentError, match="hitsides"):
        db.shade(p, n, hitsides="sideways")
    with pytest.raises(pbgi.InvalidArgumentError, match="max_solid_angle"):
        db.shade(p, n, max_solid_angle=-1)
    with pytest.raises(pbgi.InvalidArgumentError, match="radiance_contrast"):
        db.shade(p, n, radiance_contrast=-1)


def test_shade_of_no_receivers_is_empty(db):
    out = db.shade(np.zeros((0, 3)), np.zeros((0, 3)))
    assert out.occlusion.shape == (0,) and out.irradiance.shape == (0, 3)


def test_build_refuses_bad_surfels(scratch):
    p, n, r, c = disk_surfels(pitch=0.1)
    path = scratch / "refused.pbgi"
    cases = []
    q = p.copy(); q[7, 2] = np.nan
    cases.append(((q, n, r, c), r"positions\[7\] is not finite"))
    m = n.copy(); m[4] = 0
    cases.append(((p, m, r, c), r"normals\[4\] is zero"))
    s = r.copy(); s[9] = -1
    cases.append(((p, n, s, c), r"radii\[9\] = -1: a radius must be finite and > 0"))
    d = c.copy(); d[2, 0] = np.inf
    cases.append(((p, n, r, d), r"radiance\[2\] is not finite"))
    cases.append(((p, n, r[:-1], c), rf"radii: expected shape \({len(p)},\) like positions, got \({len(p) - 1},\)"))
    cases.append(((p, n, r[:, None], c), rf"radii: expected shape \({len(p)},\), got \({len(p)}, 1\)"))
    cases.append(((p.astype(np.int32), n, r, c), "positions: expected dtype float32 or float64, got int32"))
    cases.append(((p[:0], n[:0], r[:0], None), "no surfels"))
    for args, pattern in cases:
        with pytest.raises(pbgi.InvalidArgumentError, match=pattern):
            pbgi.build(path, *args)
    assert not path.exists()
    with pytest.raises(pbgi.InvalidArgumentError, match="memory"):
        pbgi.build(path, p, n, r, memory="lots")
    with pytest.raises(pbgi.InvalidArgumentError, match="layout"):
        pbgi.build(path, p, n, r, layout="random")
    with pytest.raises(pbgi.InvalidArgumentError, match="leaf size"):
        pbgi.build(path, p, n, r, leaf_size=0)
    # skip_invalid drops what it would refuse.
    q = p.copy(); q[7, 2] = np.nan
    stats = pbgi.build(path, q, n, r, c, skip_invalid=True)
    assert stats["points"] == len(p) - 1 and stats["skipped"] == 1


def test_missing_and_damaged_databases(scratch, disk_db):
    with pytest.raises(pbgi.NotFoundError, match="does not exist") as e:
        pbgi.open(scratch / "nowhere")
    assert e.value.code == 5
    with pytest.raises(pbgi.NotFoundError):
        pbgi.info(scratch / "nowhere")
    with pytest.raises(pbgi.Error, match="nowhere.ply"):
        pbgi.build_ply(scratch / "x.pbgi", scratch / "nowhere.ply")
    # Flip bytes in the middle of a copy of the store: verify names the damage.
    src = disk_db[0] / "data.mdb"
    bad = scratch / "damaged.pbgi"
    bad.mkdir(exist_ok=True)
    data = bytearray(src.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 64] = bytes(64)
    (bad / "data.mdb").write_bytes(bytes(data))
    with pytest.raises(pbgi.DataLossError) as e:
        pbgi.verify(bad)
    assert e.value.code == 15 and "page" in e.value.message
