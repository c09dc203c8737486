"""`forestslam tls-register` on the job skeleton: --start / --max-scans reach the registration
(scans before the window undecoded), run.yaml records the window and the outcome. The
registration itself is a double here (tests/test_tls_pipeline.py covers it)."""

from __future__ import annotations

import types

import numpy as np
import yaml
from typer.testing import CliRunner


def test_window_and_run_yaml(tmp_path, monkeypatch):
    import forestslam.tls.runner as runner
    from forestslam.cli.main import app

    scans = tmp_path / "walk"
    scans.mkdir()
    rng = np.random.default_rng(1)
    for i in range(10):
        xy = rng.uniform(-5, 5, (50, 2))
        np.save(scans / f"{i:03d}.npy", np.column_stack([xy, np.full(50, i + 1.0)]))
    (scans / "001.npy").write_bytes(b"garbage")  # before the window: never decoded
    reference = tmp_path / "ref.npy"
    np.save(reference, rng.uniform(-5, 5, (100, 3)))
    seen = []

    def register(scans, reference, config, initial_pose, on_frame=None):
        for scan in scans:
            seen.append(float(np.mean(scan.points[:, 2])))
            on_frame(types.SimpleNamespace(accepted=True, virtual_rms_m=0.01))
        return "run"

    def write_products(run, out_dir, config, title="", viewpoint=None, frame=None):
        (out_dir / "trajectory.tum").write_text("")
        return {
            "frames": len(seen),
            "accepted": len(seen),
            "stems": 0,
            "map_points": 0,
            "ms_features_lm_mean": 1.0,
            "coverage_tls": None,
            "unmerged": {},
        }

    monkeypatch.setattr(runner, "register_mls_to_tls", register)
    monkeypatch.setattr(runner, "write_products", write_products)
    out = tmp_path / "plot"
    args = [
        "tls-register",
        str(scans),
        "--reference",
        str(reference),
        "--sensor",
        "vlp16",
        "--out",
        str(out),
        "--start",
        "3",
        "--max-scans",
        "4",
        "--no-progress",
    ]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert seen == [4.0, 5.0, 6.0, 7.0]  # scans 3..6 (z = i + 1)
    meta = yaml.safe_load((out / "run.yaml").read_text())
    assert meta["command"] == "tls-register" and meta["start"] == 3 and meta["max_scans"] == 4
    assert meta["summary"]["status"] == "complete" and meta["summary"]["frames"] == 4
    assert meta["summary"]["read_stats"]["skipped"] == 0
    assert meta["outputs"] == ["run.yaml", "trajectory.tum"]


def test_packets_decoded_by_the_profile_and_checkpoints_every_n_frames(tmp_path, monkeypatch):
    """Like `run`: raw Velodyne packets decoded as the --sensor profile says, and every
    tls.checkpoint_every_frames frames trajectory.tum (the frames so far) and run.yaml (status
    running, their counts) are rewritten."""
    import forestslam.io
    import forestslam.tls.runner as runner
    from forestslam.io import Scan, read_tum
    from forestslam.sensors import load_profile
    from forestslam.tls.config import TlsConfig

    packets_seen, looked = [], []
    out = tmp_path / "plot"

    def read_scans(path, topic=None, start=0, packets=None):
        packets_seen.append(packets)
        return iter([Scan(float(k), np.zeros((1, 3))) for k in range(7)][start:])

    def register(scans, reference, config, initial_pose, on_frame=None):
        for scan in scans:
            meta = yaml.safe_load((out / "run.yaml").read_text())
            tum = out / "trajectory.tum"
            looked.append((meta["summary"], len(read_tum(tum)[0]) if tum.exists() else 0))
            T = np.eye(4)
            T[0, 3] = scan.stamp
            on_frame(
                types.SimpleNamespace(
                    stamp=scan.stamp, T_tls_sensor=T, accepted=scan.stamp != 1, virtual_rms_m=0.0
                )
            )
        return "run"

    monkeypatch.setattr(forestslam.io, "read_scans", read_scans)
    monkeypatch.setattr(runner, "load_reference", lambda path: np.zeros((5, 3)))
    monkeypatch.setattr(runner, "register_mls_to_tls", register)
    monkeypatch.setattr(runner, "write_products", lambda *_: {})
    config = TlsConfig(checkpoint_every_frames=3)
    runner.run_tls_register("walk.bag", "ref.laz", "vlp16", out, config=config)
    assert packets_seen == [load_profile("vlp16").packet_config()]
    # before frames 0..6: checkpoints after frames 3 and 6 (counted from 1)
    assert [n for _, n in looked] == [0, 0, 0, 3, 3, 3, 6]
    assert looked[3][0] == {"frames": 3, "accepted": 2, "status": "running"}
    assert looked[6][0]["frames"] == 6 and looked[6][0]["accepted"] == 5
    stamps, poses = read_tum(out / "trajectory.tum")
    np.testing.assert_array_equal(stamps, np.arange(6.0))  # the last checkpoint's frames
    np.testing.assert_array_equal(poses[:, 0, 3], np.arange(6.0))
