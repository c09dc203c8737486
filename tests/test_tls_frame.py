"""`tls-register` on a georeferenced (UTM) reference: recentred once at load (tls.frame), run
in the local frame, every product shifted back. The same walk on the same plot, with the
reference stored in a frame shifted by UTM, must give the same products plus UTM."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from tls_world import mls_frame, pose, reference_cloud, stand

from forestslam.tls.frame import LocalFrame

# Easting and northing of a UTM frame; elevation left at 0 (an axis under 1 km is not shifted).
UTM = np.array([500000.0, 6000000.0, 0.0])


def test_local_frame_recentres_only_large_axes_in_whole_metres():
    rng = np.random.default_rng(3)
    local = rng.uniform(-12, 12, (1000, 3))
    assert not LocalFrame.for_reference(local).shifted
    frame = LocalFrame.for_reference(local + [500000.3, 6000000.8, 1500.2])
    assert np.array_equal(frame.offset, [500000.0, 6000001.0, 1500.0])
    pts = local + [500000.3, 6000000.8, 1500.2]
    np.testing.assert_allclose(frame.points_out(frame.points_in(pts)), pts, rtol=0, atol=1e-9)
    T = pose(500001.0, 6000002.0, 0.4)
    np.testing.assert_allclose(frame.poses_out(frame.pose_in(T))[0], T, rtol=0, atol=1e-9)


def test_face_test_takes_the_files_origin_and_positions_in_the_local_frame():
    """reference_scanners on a recentred reference: the file's origin, viewpoint and configured
    positions are the file's frame, the returned positions the local frame."""
    from forestslam.tls.config import TreeConfig
    from forestslam.tls.trees import reference_scanners

    ref = reference_cloud(stand())
    utm = LocalFrame.for_reference(ref + UTM)
    local_ref = utm.points_in(ref + UTM)  # the station's frame again (offset = UTM)
    file_origin = -utm.offset[:2]
    none = reference_scanners(local_ref, TreeConfig(), file_origin_xy=file_origin)
    assert len(none.xy) == 0 and "x 499989.0..500011.0" in none.source
    assert np.array_equal(reference_scanners(local_ref, TreeConfig()).xy, [[0.0, 0.0]])
    seen = reference_scanners(local_ref, TreeConfig(), UTM + [1.0, 2.0, 1.5], None, file_origin)
    np.testing.assert_allclose(seen.xy, [[1.0, 2.0]], rtol=0, atol=1e-9)
    config = TreeConfig(reference_scanners_xy=((500003.0, 6000004.0),))
    listed = reference_scanners(local_ref, config, file_origin_xy=file_origin)
    np.testing.assert_allclose(listed.xy, [[3.0, 4.0]], rtol=0, atol=1e-9)


def _register(tmp_path, monkeypatch, name, shift, initial_pose=None):
    """run_tls_register on the tests' world (4 VLP-16 frames) with the reference (and the
    station, given as the face test's scanner) in a frame shifted by `shift`."""
    import forestslam.io
    import forestslam.tls.runner as runner
    from forestslam.io import read_tum
    from forestslam.io.trees import read_trees_csv
    from forestslam.tls.config import TlsConfig

    trees = stand()
    frames = [
        mls_frame(trees, pose(1.0 + 0.4 * k, -0.5 + 0.1 * k, 0.3 + 0.02 * k), 0.1 * k, seed=k)
        for k in range(4)
    ]
    ref_path = tmp_path / f"{name}.npy"
    np.save(ref_path, reference_cloud(trees) + shift)
    monkeypatch.setattr(
        forestslam.io, "read_scans", lambda path, topic=None, start=0, packets=None: iter(frames)
    )
    config = TlsConfig()
    config.trees.reference_scanners_xy = [shift[:2].tolist()]
    out = tmp_path / name
    runner.run_tls_register(
        "walk.bag", ref_path, "vlp16", out, config=config, initial_pose=initial_pose
    )
    _, poses = read_tum(out / "trajectory.tum")
    meta = yaml.safe_load((out / "run.yaml").read_text())
    return poses, read_trees_csv(out / "trees.csv"), meta["summary"], out


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_utm_reference_registers_with_products_in_its_frame(tmp_path, monkeypatch):
    from forestslam.io import read_cloud

    poses, trees, summary, out = _register(tmp_path, monkeypatch, "local", np.zeros(3))
    utm_poses, utm_trees, utm_summary, utm_out = _register(tmp_path, monkeypatch, "utm", UTM)
    assert summary["local_frame_offset"] == [0.0, 0.0, 0.0]
    assert utm_summary["local_frame_offset"] == UTM.tolist()
    assert utm_summary["frames"] == summary["frames"] == 4
    assert utm_summary["accepted"] == summary["accepted"] >= 1
    assert utm_summary["reference_scanners"]["xy"] == [UTM[:2].tolist()]
    # The local frame is the unshifted one up to float64 rounding of reference + UTM (under
    # 0.5 nm at 6000 km); the pipeline is continuous in its input away from decision
    # thresholds, so the products agree to far below 1 um. TUM keeps 9 decimals, trees.csv
    # 6 (0.5 um rounding each side): 1 um and 1.5 um absolute (a relative tolerance at
    # 6000 km would allow metres).
    np.testing.assert_allclose(utm_poses[:, :3, :3], poses[:, :3, :3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(utm_poses[:, :3, 3] - UTM, poses[:, :3, 3], rtol=0, atol=1e-6)
    assert len(utm_trees["x"]) == len(trees["x"]) >= 10
    for k, axis in enumerate("xyz"):
        np.testing.assert_allclose(utm_trees[axis] - UTM[k], trees[axis], rtol=0, atol=1.5e-6)
    np.testing.assert_allclose(utm_trees["dbh_m"], trees["dbh_m"], rtol=0, atol=1.5e-6)
    # plot.laz: the same map, shifted (LAZ stores 0.1 mm steps).
    cloud, utm_cloud = read_cloud(out / "plot.laz").points, read_cloud(utm_out / "plot.laz").points
    assert len(utm_cloud) == len(cloud) > 1000
    np.testing.assert_allclose(utm_cloud - UTM, cloud, rtol=0, atol=1.1e-4)


def test_initial_pose_is_given_in_the_utm_frame(tmp_path, monkeypatch):
    """--initial-pose x,y,yaw is the reference's frame: the walk's true first pose + UTM."""
    truth = pose(1.0, -0.5, 0.3)
    given = truth.copy()
    given[:3, 3] += UTM
    poses, _, summary, _ = _register(tmp_path, monkeypatch, "utm", UTM, initial_pose=given)
    assert summary["initial_pose"] == "given" and summary["accepted"] == 4
    np.testing.assert_allclose(poses[0, :3, 3] - UTM, truth[:3, 3], rtol=0, atol=0.01)


def test_checkpoints_are_in_the_references_frame(tmp_path, monkeypatch):
    """The trajectory a checkpoint writes mid-run is shifted back like the final one."""
    import types

    import forestslam.io
    import forestslam.tls.runner as runner
    from forestslam.io import Scan, read_tum
    from forestslam.tls.config import TlsConfig

    def register(scans, reference, config, initial_pose, on_frame=None):
        assert abs(reference[:, :2]).max() < 20  # registered in the local frame
        for scan in scans:
            T = np.eye(4)
            T[0, 3] = scan.stamp
            on_frame(
                types.SimpleNamespace(
                    stamp=scan.stamp, T_tls_sensor=T, accepted=True, virtual_rms_m=0.0
                )
            )
        raise RuntimeError("stopped after the checkpoints")

    frames = [Scan(float(k), np.zeros((1, 3))) for k in range(4)]
    monkeypatch.setattr(forestslam.io, "read_scans", lambda *a, **k: iter(frames))
    monkeypatch.setattr(runner, "load_reference", lambda path: reference_cloud(stand()) + UTM)
    monkeypatch.setattr(runner, "register_mls_to_tls", register)
    out = tmp_path / "plot"
    with pytest.raises(RuntimeError):
        config = TlsConfig(checkpoint_every_frames=2)
        runner.run_tls_register("walk.bag", "ref.laz", "vlp16", out, config=config)
    _, poses = read_tum(out / "trajectory.tum")
    np.testing.assert_allclose(poses[:, :3, 3] - UTM, [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
