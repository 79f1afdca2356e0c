"""Keyframes exported as BVH: keyposes-only and reconstructed files, the CLI, Blender markers."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from streamkey.bvh import read_bvh
from streamkey.cli import main
from streamkey.evaluate import reconstruct
from streamkey.export import export_keyframes_bvh, export_reconstructed_bvh, sidecar_path
from streamkey.methods import offline_method

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def walk(data_dir: Path):  # type: ignore[no-untyped-def]
    motion = read_bvh(data_dir / "07_01.bvh")
    return motion, offline_method("saliency")(motion)


def test_keyframes_only_bvh_reloads_with_the_keyframe_count_and_the_original_poses(
        walk, tmp_path: Path) -> None:
    motion, keys = walk
    out = export_keyframes_bvh(motion, keys, tmp_path / "keys.bvh")
    back = read_bvh(out)
    assert back.n_frames == len(keys) >= 5
    assert back.first_frame == 0  # no keypose is mistaken for a T-pose reference frame
    assert back.skeleton.names == motion.skeleton.names
    assert back.fps == motion.fps
    np.testing.assert_allclose(back.channels, motion.channels[keys.frames], atol=1e-4)
    meta = json.loads(sidecar_path(out).read_text())
    assert meta["frames"] == keys.frames.tolist()
    assert meta["method"] == "saliency"
    np.testing.assert_allclose(meta["times"], keys.frames / motion.fps, atol=1e-6)


def test_an_amc_clip_exports_three_rotation_channels_per_joint_and_the_same_poses(
        data_dir: Path, tmp_path: Path) -> None:
    """BVH importers (Blender's among them) read only joints with three rotation channels;
    an AMC bone has 0-3, so the export pads the missing axes at zero angle."""
    from streamkey.amc import read_amc
    from streamkey.kinematics import forward_kinematics

    motion = read_amc(data_dir / "35_01.amc")
    assert any(len([c for c in chans if c.endswith("rotation")]) in (1, 2)
               for chans in motion.skeleton.channels)  # some bones turn about 1-2 axes
    frames = np.arange(0, motion.n_frames, 40)
    back = read_bvh(export_keyframes_bvh(motion, frames, tmp_path / "keys.bvh"))
    assert all(len([c for c in chans if c.endswith("rotation")]) == 3
               for chans in back.skeleton.channels)
    np.testing.assert_allclose(
        forward_kinematics(back.skeleton, back.channels).positions,
        forward_kinematics(motion.skeleton, motion.channels[frames]).positions, atol=1e-3)


def test_reconstructed_bvh_is_the_interpolation_with_the_keys_exact(walk, tmp_path: Path) -> None:
    motion, keys = walk
    back = read_bvh(export_reconstructed_bvh(motion, keys, tmp_path / "rebuilt.bvh"))
    assert back.n_frames == motion.n_frames
    assert back.first_frame == motion.first_frame
    np.testing.assert_allclose(back.channels, reconstruct(motion, keys), atol=1e-4)
    np.testing.assert_allclose(back.channels[keys.frames], motion.channels[keys.frames],
                               atol=1e-4)
    between = np.setdiff1d(np.arange(motion.first_frame, motion.n_frames), keys.frames)
    assert np.abs(back.channels[between] - motion.channels[between]).max() > 0.1


def test_extract_exports_one_file_per_clip_and_method_with_a_pattern(
        data_dir: Path, tmp_path: Path) -> None:
    clips = [str(data_dir / "07_01.bvh"), str(data_dir / "05_02.bvh")]
    pattern = str(tmp_path / "{stem}_{method}.bvh")
    code = main(["extract", *clips, "--method", "saliency,speed", "-q",
                 "-o", str(tmp_path / "keys.json"), "--export-bvh", pattern])
    assert code == 0
    result = json.loads((tmp_path / "keys.json").read_text())
    for entry in result["files"]:
        stem = Path(entry["file"]).stem
        for method, keys in entry["methods"].items():
            back = read_bvh(tmp_path / f"{stem}_{method}.bvh")
            assert back.n_frames == len(keys["keyframes"])


def test_extract_refuses_an_export_name_that_several_results_would_share(
        data_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["extract", str(data_dir / "07_01.bvh"), "--method", "saliency,speed", "-q",
                 "-o", str(tmp_path / "k.json"), "--export-bvh", str(tmp_path / "k.bvh")])
    assert code == 2
    assert "{stem} and/or {method}" in capsys.readouterr().err
    assert not (tmp_path / "k.bvh").exists()


def _blender_example():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("blender_markers",
                                                  ROOT / "examples" / "blender_markers.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # imports without Blender
    return module


def test_blender_example_turns_extract_json_and_sidecar_into_markers(
        walk, data_dir: Path, tmp_path: Path) -> None:
    motion, keys = walk
    blender = _blender_example()
    main(["extract", str(data_dir / "07_01.bvh"), "--method", "saliency,speed", "-q",
          "-o", str(tmp_path / "keys.json")])
    data = json.loads((tmp_path / "keys.json").read_text())
    markers = blender.markers_from_json(data, method="saliency")
    assert markers == [(f"saliency {f}", 1 + f) for f in keys.frames.tolist()]
    assert len(blender.markers_from_json(data)) > len(markers)  # both methods
    out = export_keyframes_bvh(motion, keys, tmp_path / "keys.bvh")
    side = json.loads(sidecar_path(out).read_text())
    assert blender.markers_from_json(side, start=0) == [(f"saliency {f}", f)
                                                         for f in keys.frames.tolist()]
    half = blender.markers_from_json(side, start=1, fps_scale=0.25)
    assert [f for _, f in half] == [1 + round(f / 4) for f in keys.frames.tolist()]
