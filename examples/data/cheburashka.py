"""Author the Cheb's 17-bone skeleton and its animation (run from the repo root).

    .venv/bin/python examples/data/cheburashka.py

Writes ``cheburashka.tgf`` (18 joints, 17 bones: spine, neck, head, two bones
per ear, shoulder/upper/lower arm, thigh/shin) and ``cheburashka-anim.dmat``
(40 frames in libigl's stacked LBS format, 12 x 17 rows). The joints were
placed inside the mesh by hand from slices of ``cheburashka.off`` (y is up,
the character faces +z); the motion is forward kinematics of smooth
sinusoidal joint rotations (ears flap, arms wave, legs step, head nods and
turns, the spine bends), frame 0 being the rest pose. Deterministic.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent

JOINTS = np.array([
    [0.500, 0.240, 0.480],  # 1 pelvis
    [0.500, 0.470, 0.490],  # 2 chest
    [0.500, 0.550, 0.490],  # 3 neck
    [0.500, 0.710, 0.520],  # 4 head
    [0.310, 0.750, 0.510],  # 5 left ear base
    [0.100, 0.750, 0.520],  # 6 left ear tip
    [0.700, 0.750, 0.485],  # 7 right ear base
    [0.890, 0.752, 0.480],  # 8 right ear tip
    [0.370, 0.450, 0.470],  # 9 left shoulder
    [0.300, 0.390, 0.470],  # 10 left elbow
    [0.245, 0.321, 0.492],  # 11 left hand
    [0.630, 0.450, 0.470],  # 12 right shoulder
    [0.700, 0.390, 0.470],  # 13 right elbow
    [0.725, 0.315, 0.505],  # 14 right hand
    [0.410, 0.150, 0.510],  # 15 left knee
    [0.420, 0.090, 0.570],  # 16 left foot
    [0.590, 0.150, 0.510],  # 17 right knee
    [0.580, 0.090, 0.570],  # 18 right foot
])
# (parent joint, child joint), 1-based as in TGF
BONES = np.array([[1, 2], [2, 3], [3, 4], [4, 5], [5, 6], [4, 7], [7, 8], [2, 9], [9, 10], [10, 11],
                  [2, 12], [12, 13], [13, 14], [1, 15], [15, 16], [1, 17], [17, 18]])
NAMES = ["spine", "neck", "head", "ear_l_base", "ear_l", "ear_r_base", "ear_r", "shoulder_l", "arm_l",
         "forearm_l", "shoulder_r", "arm_r", "forearm_r", "thigh_l", "shin_l", "thigh_r", "shin_r"]

# bone: (axis, amplitude in degrees, cycles over the clip, phase in cycles)
MOTION = {
    "spine": [((1, 0, 0), 12, 1, 0.0), ((0, 1, 0), 10, 1, 0.25)],
    "neck": [((1, 0, 0), 8, 2, 0.1)],
    "head": [((1, 0, 0), 18, 1, 0.3), ((0, 1, 0), 30, 1, 0.0)],
    "ear_l_base": [((0, 0, 1), 10, 2, 0.0)],
    "ear_l": [((0, 1, 0), 40, 2, 0.0), ((0, 0, 1), 15, 3, 0.2)],
    "ear_r_base": [((0, 0, 1), -10, 2, 0.0)],
    "ear_r": [((0, 1, 0), -40, 2, 0.5), ((0, 0, 1), -15, 3, 0.2)],
    "shoulder_l": [((0, 0, 1), 12, 1, 0.0)],
    "arm_l": [((0, 0, 1), -60, 1, 0.0), ((1, 0, 0), 25, 2, 0.0)],
    "forearm_l": [((0, 1, 0), 50, 2, 0.1)],
    "shoulder_r": [((0, 0, 1), -12, 1, 0.5)],
    "arm_r": [((0, 0, 1), 60, 1, 0.5), ((1, 0, 0), -25, 2, 0.0)],
    "forearm_r": [((0, 1, 0), -50, 2, 0.6)],
    "thigh_l": [((1, 0, 0), 30, 2, 0.0)],
    "shin_l": [((1, 0, 0), -25, 2, 0.25)],
    "thigh_r": [((1, 0, 0), -30, 2, 0.0)],
    "shin_r": [((1, 0, 0), 25, 2, 0.25)],
}
FRAMES = 40


def rotation(axis, angle):
    """Rodrigues' rotation matrix."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def pose(t: float) -> np.ndarray:
    """(17, 3, 4) bone transforms at clip time t in [0, 1): forward kinematics."""
    B = BONES - 1
    child_of = {int(c): b for b, (_, c) in enumerate(B)}
    G = np.zeros((len(B), 4, 4))
    for b, (p, _) in enumerate(B):  # parents come before children in BONES
        R = np.eye(3)
        for axis, amp, cycles, phase in MOTION[NAMES[b]]:
            R = R @ rotation(axis, np.radians(amp) * np.sin(2 * np.pi * (cycles * t + phase))
                             - np.radians(amp) * np.sin(2 * np.pi * phase))
        j = JOINTS[p]
        local = np.eye(4)
        local[:3, :3] = R
        local[:3, 3] = j - R @ j             # rotate about the bone's head joint
        parent = child_of.get(int(p))
        if parent is None:                   # roots: a gentle bob of the whole body
            root = np.eye(4)
            root[1, 3] = 0.02 * np.sin(2 * np.pi * 2 * t)
            G[b] = root @ local
        else:
            G[b] = G[parent] @ local
    return G[:, :3, :]


def main():
    import sys

    sys.path.insert(0, str(HERE.parents[1]))
    from rigslim.io import write_dmat
    from rigslim.io.animation import transforms_to_stacked
    from rigslim.io.atomic import atomic_path

    with atomic_path(HERE / "cheburashka.tgf") as tmp:
        lines = [f"{i + 1} {x:.3f} {y:.3f} {z:.3f}" for i, (x, y, z) in enumerate(JOINTS)]
        lines += ["#"] + [f"{a} {b}" for a, b in BONES] + ["#"]
        tmp.write_text("\n".join(lines) + "\n")
    T = np.stack([pose(f / FRAMES) for f in range(FRAMES)])
    write_dmat(HERE / "cheburashka-anim.dmat", transforms_to_stacked(T))
    print(f"wrote cheburashka.tgf ({len(JOINTS)} joints, {len(BONES)} bones) and "
          f"cheburashka-anim.dmat ({FRAMES} frames)")


if __name__ == "__main__":
    main()
