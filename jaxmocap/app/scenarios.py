"""Adapters from simulated scenarios to the methods' inputs.

A `jaxmocap.sensors.Scenario` stores each sequence as a dict of named arrays
(`scenario.sequence(i)["imu_ori"]`, `["det_keypoints"]`, ...). The methods take typed
inputs (`InertialSetup`, `VIPData`, `InteractionObservations`) and know nothing of those
keys; the functions here read the dict and build the inputs. Until the next release the
old names (`methods.inertial.from_scenario`, `methods.visual_inertial.from_scenario`,
`tracker_keypoints`, `associated_keypoints`, `InteractionObservations.from_scenario`)
still call these.
"""

from __future__ import annotations

import numpy as np

from ..body.model import Body
from ..methods.association import Association, AssociationModel, associate
from ..methods.inertial import InertialSetup, calibrate
from ..methods.interaction import InteractionObservations
from ..methods.visual_inertial import tracker_hypotheses, vip_data
from ..objects import RigidObject
from ..priors.pose_prior import PosePrior
from ..sensors.detector import person_track
from ..sensors.segmentation import object_candidates

__all__ = ["inertial_setup", "vip_sequence", "tracker_keypoints", "associated_keypoints", "interaction_observations"]


def inertial_setup(
    scenario, index: int, body: Body, person: int = 0, truth_init: bool = True, start: int = 0, **kw
) -> InertialSetup:
    """Calibrate sequence `index` of a `jaxmocap.sensors.Scenario` (measured IMU readings).

    x₀ is the true pose at frame `start` (the thesis's "initial pose provided with the
    dataset"), and the setup holds the readings from `start` on; pass
    `start=first_complete_frame(scenario.sequence(index)["imu_ori"][person])` when frame 0
    may have dropped samples (the setup then starts there: crop the truth alike).
    kw go to `methods.inertial.calibrate`.
    """
    seq = scenario.sequence(index)
    p = person
    n = len(seq["imu_ori"][p])
    if not isinstance(start, (int, np.integer)) or not 0 <= start < n:
        raise ValueError(f"start={start!r} must be a frame index in 0 .. {n - 1}.")
    return calibrate(
        body, seq["imu_bones"], seq["imu_vertices"], seq["imu_ori"][p][start:], seq["imu_acc"][p][start:],
        seq["poses"][p][start], scenario.config.fps, betas=seq["betas"][p], trans0=seq["trans"][p][start], **kw,
    )  # fmt: skip


def vip_sequence(scenario, index: int, body: Body, person: int = 0, x0=None, keypoints=None, sensors=None, **kw):
    """`VIPData` for one IMU wearer of a camera+IMU scenario (`ScenarioConfig` with a moving
    camera, `camera_imu=True`, keypoints "coco18").

    x0 defaults to the true pose at frame 0. keypoints (T, 18, 3) replaces the detections
    (VIP-2D passes the true projections); by default the person's detections are taken by
    the simulator's identity labels (`associated_keypoints` gives them by association).
    sensors: indices of the body sensors to use (default all).
    Returns (data, truth, bones) with truth = {poses, trans, betas, cam_R, cam_t} of that
    person and bones the bone of each sensor used.
    """
    seq = scenario.sequence(index)
    missing = [k for k in ("cam_imu_ori", "det_keypoints", "imu_ori") if k not in seq]
    if missing:
        raise ValueError(f"scenario has no {missing}: VIP needs body IMUs, a camera IMU and COCO-18 detections.")
    if keypoints is None:
        keypoints = person_track(seq["det_keypoints"], seq["det_person"], person)[:, 0]
    x0 = seq["poses"][person][0] if x0 is None else x0
    K = seq["cam_K"][0]
    idx = np.arange(len(seq["imu_bones"])) if sensors is None else np.asarray(sensors)
    bones = tuple(int(b) for b in np.asarray(seq["imu_bones"])[idx])
    data = vip_data(
        body, bones, np.asarray(seq["imu_vertices"])[idx], seq["imu_ori"][person][:, idx], seq["imu_acc"][person][:, idx], x0,
        scenario.config.fps, seq["cam_imu_ori"], seq["cam_imu_acc"], K, keypoints,
        scenario.config.cameras.height, betas=seq["betas"][person], **kw,
    )  # fmt: skip
    truth = {"poses": seq["poses"][person], "trans": seq["trans"][person], "betas": seq["betas"][person],
             "cam_R": seq["cam_R"][0], "cam_t": seq["cam_t"][0]}  # fmt: skip
    return data, truth, bones


def tracker_keypoints(scenario, index: int, body: Body, people=(0, 1), x0s=None, prior: PosePrior | None = None):
    """World COCO-18 keypoints (P, T, 18, 3) of the Inertial Tracker's poses (eq. 4.10) of each
    wearer in `people`, at translation 0 (IMUs do not observe position): the hypotheses of
    the first association (eq. 4.11). x0s: one given initial pose (24, 3) per person
    (default each person's true frame-0 pose)."""
    seq = scenario.sequence(index)
    T = len(seq["cam_imu_ori"])
    # The tracker reads no image: a placeholder detection only satisfies `vip_data`'s check.
    dummy = np.ones((T, 18, 3))
    datas = [vip_sequence(scenario, index, body, person=p, x0=None if x0s is None else x0s[k], keypoints=dummy,
                          prior=prior) for k, p in enumerate(people)]  # fmt: skip
    return tracker_hypotheses([d for d, _, _ in datas], datas[0][2])


def associated_keypoints(
    scenario,
    index: int,
    body: Body,
    people=(0, 1),
    x0s=None,
    model: AssociationModel | None = None,
    prior: PosePrior | None = None,
    **kw,
) -> Association:
    """Detections of a scenario assigned to its wearers `people` by association (eq.
    4.11-4.18) from their Inertial Tracker keypoints (`tracker_keypoints`). `.keypoints[k]`
    (T, 18, 3) is person people[k]'s input to `vip_sequence(keypoints=…)`; kw go to
    `association.associate`."""
    seq = scenario.sequence(index)
    joints3d = tracker_keypoints(scenario, index, body, people, x0s, prior)
    return associate(joints3d, seq["cam_K"][0], seq["cam_imu_ori"], seq["det_keypoints"][0], model=model, **kw)


def interaction_observations(scenario, i: int = 0, seed: int = 0, num_distractors: int = 2) -> InteractionObservations:
    """Sequence i of a `make_scenario` scene with an object, cameras, body25 keypoints and
    depth points (`sensors.scenario.interaction_config`); candidates come from
    `sensors.segmentation.object_candidates` (mask errors and distractors)."""
    s = scenario.sequence(i)
    missing = [k for k in ("obj_R", "det_keypoints", "depth_points", "labels") if k not in s]
    if missing:
        raise ValueError(f"the scenario lacks {missing}: make it with sensors.scenario.interaction_config().")
    P = s["poses"].shape[0]
    kp = s["det_keypoints"][:, :, 0]  # (C, T, K, 3), slot 0 (one person, no distractors)
    lab, pts, val = s["depth_labels"], s["depth_points"], s["depth_valid"]
    to_tv = lambda x: np.swapaxes(np.asarray(x), 0, 1)  # noqa: E731  (C, T, ...) -> (T, C, ...)
    cand, _ = object_candidates(s["labels"], P, np.random.default_rng(seed), num_distractors)
    obj = RigidObject(s["obj_vertices"], s["obj_faces"], scenario.meta.get("object") or "object")
    return InteractionObservations(
        K=np.asarray(s["cam_K"], np.float64), R=np.asarray(s["cam_R"][:, 0], np.float64),
        t=np.asarray(s["cam_t"][:, 0], np.float64), keypoints=to_tv(kp).astype(np.float64),
        body_points=to_tv(pts), body_valid=to_tv(val & (lab == 0)),
        object_points=to_tv(pts), object_valid=to_tv(val & (lab == P)), candidates=cand,
        obj=obj, fps=float(scenario.config.fps),
    )  # fmt: skip
