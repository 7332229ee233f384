"""Video Inertial Poser inputs from a 3DPW sequence: simulated IMUs on the file's motion.

The pickles carry no IMU readings, so the body IMUs are simulated from the person's
reference poses (`errors.simulate_imu`, noise-free unless an error model is given) and the
camera IMU from the camera poses (`moving_camera.camera_imu`, axes = camera axes); the detections
are the file's own OpenPose COCO-18 keypoints. Everything is at the images' 30 Hz.
"""

from __future__ import annotations

import numpy as np

from ..formats.threedpw import ThreeDPWSequence, valid_span
from .errors import IMUErrorModel, simulate_imu
from .imu import imu_placement
from .moving_camera import camera_imu

__all__ = ["vip_inputs"]


def vip_inputs(
    sequence: ThreeDPWSequence,
    person: int = 0,
    body=None,
    imu_set: str = "totalcapture13",
    frames: slice | None = None,
    imu_errors: IMUErrorModel | None = None,
    seed: int = 0,
    keypoints=None,
) -> tuple[dict, dict]:
    """The arguments of `methods.visual_inertial.vip_data` for one person: `vip_data(**inputs)`.

    Args:
        sequence: `formats.load_threedpw(...)`; person: which of its people wears the IMUs.
        body: the body model (default `default_body("low")`). The file's betas are SMPL's:
            they are used with an SMPL-family body and replaced by zeros on the default body,
            whose shape space is another.
        imu_set: `imu.SENSOR_SETS` name (VIP's suit: "totalcapture13").
        frames: the frames to use (default: the person's longest run of `campose_valid`
            frames; VIP calibrates on the first, and an unaligned camera pose would make the
            camera IMU contradict the images).
        imu_errors: sensor error model (default none); seed: its random draw.
        keypoints: (T', 18, 3) detections replacing the file's (e.g. true projections).
    Returns:
        (inputs, truth): inputs has body, bones, vertices, orientation (T', S, 3, 3),
        acceleration (T', S, 3), x0 (24, 3, the reference pose of the first frame), fps,
        cam_orientation (T', 3, 3), cam_acceleration (T', 3), K, keypoints (T', 18, 3),
        image_height and betas; truth has poses, trans, betas, cam_R, cam_t and frames.
    """
    from ..body.io import default_body

    body = default_body("low") if body is None else body
    if not 0 <= person < sequence.num_people:
        raise ValueError(f"person {person} is not in this sequence of {sequence.num_people} people.")
    frames = valid_span(sequence.valid[person]) if frames is None else frames
    poses, trans = sequence.poses[person][frames], sequence.trans[person][frames]
    cam_R, cam_t = sequence.cam_R[frames], sequence.cam_t[frames]
    if len(poses) < 2:
        raise ValueError(f"frames {frames} hold {len(poses)} frame(s); VIP needs a sequence (2 or more).")
    betas = np.zeros(body.num_betas)
    if body.kind != "default":
        n = min(body.num_betas, sequence.betas.shape[1])
        betas[:n] = sequence.betas[person, :n]
    placement = imu_placement(body, imu_set)
    rng = np.random.default_rng(seed)
    _, measured, _ = simulate_imu(body, placement, poses, betas, trans, sequence.fps,
                                  IMUErrorModel.off() if imu_errors is None else imu_errors, rng)  # fmt: skip
    cam = camera_imu(cam_R, cam_t, sequence.fps)
    kp = sequence.keypoints[person][frames] if keypoints is None else np.asarray(keypoints, np.float64)
    inputs = {
        "body": body, "bones": placement.bones, "vertices": placement.vertices,
        "orientation": np.asarray(measured.orientation), "acceleration": np.asarray(measured.acceleration),
        "x0": poses[0], "fps": sequence.fps, "cam_orientation": np.asarray(cam.orientation[:, 0]),
        "cam_acceleration": np.asarray(cam.acceleration[:, 0]), "K": sequence.K, "keypoints": kp,
        "image_height": sequence.height, "betas": betas,
    }  # fmt: skip
    truth = {"poses": poses, "trans": trans, "betas": betas, "cam_R": cam_R, "cam_t": cam_t, "frames": frames}
    return inputs, truth
