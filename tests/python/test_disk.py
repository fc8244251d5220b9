"""The disk through Python: analytic occlusion and irradiance, the cut's coverage, and that
dtype, strides and the PLY path build the same database."""
import os

import numpy as np
import pytest

import pbgi
from conftest import (DISK_HEIGHT, DISK_RADIANCE, DISK_RADIUS, axis_receivers, disk_surfels,
                      form_factor)


def test_build_stats_and_info(disk_db):
    path, (p, _, _, _), stats = disk_db
    assert stats["points"] == len(p)
    assert stats["leaves"] >= len(p) / 8
    assert stats["nodes"] > stats["leaves"]
    info = pbgi.info(path)
    assert info["point_count"] == len(p)
    assert info["channels"] == "radiance"
    assert info["leaf_size"] == 8
    assert info["page_size"] == 4096 - 16
    assert info["layout"] == "coherent"
    assert info["bounds_lo"][2] == pytest.approx(1.0)
    assert pbgi.open(path).info() == info
    report = pbgi.verify(path)
    assert report["point_records"] == len(p)
    assert report["bad_pages"] == 0 and report["tree_checked"]


@pytest.mark.parametrize("mode", ["occlusion", "irradiance"])
def test_disk_occlusion_matches_form_factor(disk_db, mode):
    path, _, _ = disk_db
    db = pbgi.open(path)
    positions, normals, h = axis_receivers(64)
    out = db.shade(positions, normals, mode=mode, threads=2)
    want = form_factor(DISK_RADIUS, h)
    assert out.occlusion.dtype == np.float32 and out.occlusion.shape == (64,)
    np.testing.assert_allclose(out.occlusion, want, rtol=0.03)
    if mode == "occlusion":
        assert out.irradiance is None
    else:
        assert out.irradiance.shape == (64, 3)
        # A Lambertian emitter of radiance L: E = pi L F.
        want_e = np.pi * DISK_RADIANCE[None, :] * want[:, None]
        np.testing.assert_allclose(out.irradiance, want_e, rtol=0.05)
    assert out.stats["receivers"] == 64 and out.stats["clusters"] > 0


def test_a_uniform_emitter_has_no_radiance_contrast(disk_db):
    # Every node of a uniform disk has contrast 0, so the cut that sees radiance takes the same
    # nodes as the plain one: the same bits.
    path, _, _ = disk_db
    db = pbgi.open(path)
    positions, normals, _ = axis_receivers(32)
    plain = db.shade(positions, normals, radiance_contrast=0)
    seen = db.shade(positions, normals)
    np.testing.assert_array_equal(plain.irradiance, seen.irradiance)
    assert plain.stats["clusters"] == seen.stats["clusters"]


def test_glossy_mode_returns_all_three(disk_db):
    path, _, _ = disk_db
    db = pbgi.open(path)
    positions, normals, _ = axis_receivers(16)
    out = db.shade(positions, normals, normals, mode="glossy", lobe="phong", phong_exponent=8)
    assert out.glossy.shape == (16, 3) and out.irradiance.shape == (16, 3)
    # Looking straight at a uniform emitter that fills most of the lobe: close to its radiance.
    assert np.all(out.glossy[:, 2] > 0.5 * DISK_RADIANCE[2])
    assert np.all(out.glossy[:, 2] <= DISK_RADIANCE[2] * 1.05)


def test_gather_represents_every_surfel_once(disk_db):
    path, (p, _, _, _), _ = disk_db
    db = pbgi.open(path)
    g = db.gather([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    assert g.clusters.dtype == pbgi.CLUSTER_DTYPE and g.surfels.dtype == pbgi.SURFEL_DTYPE
    assert len(g.clusters) > 0
    covered = np.zeros(len(p), dtype=np.int64)
    for first, count in zip(g.clusters["first_point"], g.clusters["point_count"]):
        covered[first:first + count] += 1
    covered[g.surfel_ids.astype(np.int64)] += 1
    assert np.all(covered == 1)
    area = g.clusters["area"].sum() + (np.pi * g.surfels["radius"] ** 2).sum()
    assert area == pytest.approx(len(p) * 0.01**2, rel=1e-3)
    assert np.all(g.clusters["bounds_lo"][:, 2] >= 1.0 - 1e-5)
    # A cluster's surfels are the ones its range names, inside its bounds.
    reader = db.reader()
    c = g.clusters[np.argmax(g.clusters["point_count"])]
    pts = reader.read_points(c["first_point"], c["point_count"])
    assert len(pts) == c["point_count"]
    assert np.all(pts["position"] >= c["bounds_lo"] - 1e-6)
    assert np.all(pts["position"] <= c["bounds_hi"] + 1e-6)
    # Facing away, nothing is in front.
    assert len(db.gather([0, 0, 0], [0, 0, -1])) == 0
    # A finer cut: more elements for the same coverage.
    fine = db.gather([0, 0, 0], [0, 0, 1], max_solid_angle=0.003)
    assert len(fine) > len(g)


def test_float32_and_strided_inputs_build_the_same_database(scratch, disk_db):
    path, (p, n, r, c), _ = disk_db
    # Every array float32, the positions a strided view into a wider array.
    wide = np.zeros((len(p), 6), dtype=np.float32)
    wide[:, ::2] = p
    view = wide[:, ::2]
    assert not view.flags.c_contiguous
    other = scratch / "disk32.pbgi"
    pbgi.build(other, view, n.astype(np.float32), r.astype(np.float32),
               np.asfortranarray(c.astype(np.float32)), leaf_size=8, page_size=4096 - 16)
    positions, normals, _ = axis_receivers(32)
    a = pbgi.open(path).shade(positions, normals, threads=1)
    b = pbgi.open(other).shade(positions.astype(np.float32), normals[:, :], threads=1)
    np.testing.assert_array_equal(a.occlusion, b.occlusion)
    np.testing.assert_array_equal(a.irradiance, b.irradiance)


def write_ply(path, p, n, r, c):
    header = (
        "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % len(p)
        + "".join(f"property float {x}\n" for x in "x y z nx ny nz radius r g b".split())
        + "end_header\n")
    rec = np.concatenate([p, n, r[:, None], c], axis=1).astype("<f4")
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(rec.tobytes())


def test_build_ply_equals_build_arrays(scratch, disk_db):
    path, (p, n, r, c), _ = disk_db
    ply = scratch / "disk.ply"
    write_ply(ply, p, n, r, c)
    seen = []
    stats = pbgi.build_ply(scratch / "disk-ply.pbgi", ply, leaf_size=8, page_size=4096 - 16,
                           progress=lambda *a: seen.append(a))
    assert stats["points"] == len(p)
    assert seen and seen[-1] == ("done", len(p), len(p))
    assert pbgi.info(scratch / "disk-ply.pbgi")["channels"] == "radiance"
    positions, normals, _ = axis_receivers(16)
    a = pbgi.open(path).shade(positions, normals)
    b = pbgi.open(scratch / "disk-ply.pbgi").shade(positions, normals)
    np.testing.assert_array_equal(a.occlusion, b.occlusion)


def test_build_options_reach_the_builder(scratch):
    p, n, r, _ = disk_surfels(pitch=0.05)
    path = scratch / "options.pbgi"
    stats = pbgi.build(path, p, n, r, leaf_size=4, page_size="8K", layout="postorder",
                       threads=2, memory=16 << 20)
    info = pbgi.info(path)
    assert info["channels"] == "occlusion"  # no radiance given
    assert info["layout"] == "postorder" and info["leaf_size"] == 4
    assert info["page_size"] == 8192
    assert stats["threads"] >= 1
    # Radiance asked of an occlusion-only database.
    with pytest.raises(pbgi.FailedPreconditionError) as e:
        pbgi.open(path).shade(p[:4] * 0, -n[:4])
    assert "occlusion" in e.value.message
    assert pbgi.open(path).shade(p[:4] * 0, -n[:4], mode="occlusion").occlusion.shape == (4,)


def test_a_two_sided_disk_shows_each_sides_radiance(scratch):
    # The disk faces down (normal -z) at height 1, made two-sided with a different back: below
    # it a receiver sees the front's radiance, above it (facing down) the back's; E = pi L F
    # either way. Gathered surfels carry both.
    p, n, r, c = disk_surfels(pitch=0.02)
    back = np.tile([0.0, 2.0, 0.125], (len(p), 1))
    path = os.path.join(scratch, "two_sided_disk.pbgi")
    pbgi.build(path, p, n, r, c, two_sided=np.ones(len(p), dtype=bool), back_radiance=back,
               memory="64M")
    assert pbgi.info(path)["back_radiance"] is True
    db = pbgi.open(path)
    below, up, h = axis_receivers(8)
    above = below.copy()
    above[:, 2] = 2.0 * DISK_HEIGHT - below[:, 2]
    want = form_factor(DISK_RADIUS, h)
    # Clusters that are not along the axes regularise P(w) / A(w) with a little of the mean over
    # all directions, which holds both sides, and order 2 rings: some of the other side's
    # radiance shows there (docs/design.md, "Radiance per side"), hence the absolute term, 1.5 %
    # of the brighter side's. This disk lies along an axis: its clusters show each side's own.
    brightest = np.maximum(DISK_RADIANCE, back[0]).max()
    for where, normal, radiance in ((below, up, DISK_RADIANCE), (above, -up, back[0])):
        out = db.shade(where, normal, threads=2)
        np.testing.assert_allclose(out.occlusion, want, rtol=0.03)
        exact = np.pi * radiance[None, :] * want[:, None]
        assert np.all(np.abs(out.irradiance - exact) <=
                      0.05 * exact + 0.015 * np.pi * brightest * want[:, None])
    g = db.gather(below[0], up[0], max_solid_angle=1e-4)
    assert len(g.surfels) > 0 and g.surfels["two_sided"].all()
    np.testing.assert_allclose(g.surfels["back_radiance"], back[: len(g.surfels)], rtol=2e-3)
    # Without back_radiance a two-sided surfel shows its radiance on both sides, and the
    # database stores no back.
    both = os.path.join(scratch, "two_sided_same.pbgi")
    pbgi.build(both, p, n, r, c, two_sided=np.ones(len(p)), memory="64M")
    assert pbgi.info(both)["back_radiance"] is False
    out = pbgi.open(both).shade(above, -up, threads=2)
    np.testing.assert_allclose(out.irradiance, np.pi * DISK_RADIANCE[None, :] * want[:, None],
                               rtol=0.05)
    with pytest.raises(pbgi.InvalidArgumentError, match="back_radiance needs two_sided"):
        pbgi.build(both, p, n, r, c, back_radiance=back)
