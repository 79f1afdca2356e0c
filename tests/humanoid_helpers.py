"""A CMU clip's motion on the built-in humanoid skeleton, for the VMC tests (our sender and
the third-party one): the humanoid bones take the CMU joints' channels, the root scaled to
metres."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from streamkey.bvh import read_bvh, write_bvh
from streamkey.kinematics import body_height
from streamkey.motion import Motion
from streamkey.rigs import humanoid_skeleton

# humanoid bone <- CMU joint (Neck1 and the hip joints have no humanoid bone)
FROM_CMU = {"Hips": "Hips", "Spine": "LowerBack", "Chest": "Spine", "UpperChest": "Spine1",
            "Neck": "Neck", "Head": "Head"}
for _s, _c in (("Left", "L"), ("Right", "R")):
    FROM_CMU |= {f"{_s}UpperLeg": f"{_s}UpLeg", f"{_s}LowerLeg": f"{_s}Leg",
                 f"{_s}Foot": f"{_s}Foot", f"{_s}Toes": f"{_s}ToeBase",
                 f"{_s}Shoulder": f"{_s}Shoulder", f"{_s}UpperArm": f"{_s}Arm",
                 f"{_s}LowerArm": f"{_s}ForeArm", f"{_s}Hand": f"{_s}Hand",
                 f"{_s}ThumbProximal": f"{_c}Thumb", f"{_s}IndexProximal": f"{_s}FingerBase",
                 f"{_s}IndexIntermediate": f"{_s}HandIndex1"}


def humanoid_clip(clip: Path, folder: Path) -> tuple[Path, Motion]:
    """`clip` (a CMU BVH) on the humanoid skeleton, written into `folder` and read back."""
    cmu = read_bvh(clip)
    skel = humanoid_skeleton()
    channels = np.zeros((cmu.n_frames - cmu.first_frame, skel.n_channels))
    for j, name in enumerate(skel.names):
        src = cmu.skeleton.names.index(FROM_CMU[name])
        assert cmu.skeleton.channels[src] == skel.channels[j]
        n, lo = len(skel.channels[j]), cmu.skeleton.channel_start[src]
        channels[:, skel.channel_start[j]: skel.channel_start[j] + n] = (
            cmu.channels[cmu.first_frame:, lo: lo + n])
    channels[:, :3] *= body_height(skel) / body_height(cmu.skeleton)
    path = folder / f"humanoid_{clip.stem}.bvh"
    write_bvh(Motion(skel, channels, cmu.fps, 0, f"humanoid_{clip.stem}"), path)
    return path, read_bvh(path)
