"""Association of 2D detections with IMU wearers (VIP, von Marcard §4.3.2, eq. 4.11-4.18).

Every detection v of frame t and every wearer l make a hypothesis H(l, v). Each one gets a
camera M_H fitted to the 3D keypoints of person l's hypothesis pose (e.g. the Inertial
Tracker's) against v, and three kinds of features:

    unary (eq. 4.13-4.14)     f_un = e_img(H, M_H) · e_cam(H, M_H)
    inter-frame (eq. 4.15-4.17), same person, 0 < |t − t'| <= window:
                              f_trans = ‖M_H r_t − M_H' r_t'‖, f_ori = ‖log((R_H R_t)ᵀ R_H' R_t')‖,
                              f_time = |t − t'|
                              (+ two detections on one 2D track: see cross_tracks below)
    intra-frame (eq. 4.18), two people in one frame: f_intra(H, H̲), f_intra(H', H̲), the
                              camera centre of each hypothesis against the meta camera H̲
                              fitted to both.

Logistic regression maps features to costs c = −⟨f, α⟩ (§4.4.1; α in
`association_weights.json`, trained by `experiments/train_association.py`), and the binary
quadratic program of eq. 4.11-4.12 is linearised and solved by HiGHS (`scipy.optimize.milp`).

Choices that are ours (the thesis leaves them open):
  - Hypothesis cameras M_H: world-to-camera (R, t), the rotation R_H the camera IMU's
    (measured, §4.2.3) and t fitted; without the IMU all six degrees from a DLT start.
    Measured on a training scene (2 wearers, 3 bystanders): the detection with the
    lowest f_un is the right one in 97.5 % of frames with the rotation known, 90 % with it
    free — a free rotation also fits a bystander who faces another way. Fitted by
    `jaxmocap.solve` (LM, Marquardt damping, at most 30 steps, the engine's stopping
    rules) in normalised image coordinates (pixels / focal length), so the features do
    not depend on the image size.
  - e_img divides by Σ w_k instead of N_joints (eq. 4.13): otherwise a detection with few or
    low-confidence keypoints (typical of false detections) looks consistent for that alone.
  - Root r_t = mid-hip, root orientation R_t = the frame of the hip line and the mid-hip →
    neck direction: the hypotheses are COCO-18 keypoints, not poses.
  - Meta camera M_H̲ (eq. 4.18): one translation per person unless `positions_known` (the
    Inertial Tracker does not observe where people stand) and then, so that the feature
    is not identically 0, a free rotation started at the IMU's: it measures whether both
    detections agree with one camera rotation. With positions known: the IMU rotation and
    one translation (the thesis's camera-centre consistency).
  - Features enter the regression as log(f + ε) (they are heavy-tailed: a fit that fails
    gives values 10³ times the typical ones); f_time as |t − t'| / window.
  - Hypotheses with a unary probability below `min_probability` or fewer than 5 detected
    keypoints are dropped before the pairs are built (the graph stays small).
  - Pair costs are scaled by one trained `pair_scale`: each node has up to 2·window
    inter-frame edges and their log-odds are not independent evidence.
  - Long-range penalties: inter-frame pairs whose log-odds say "two people" are also kept
    up to `penalty_window` frames apart (log-odds of the same regression, f_time
    extrapolated). Within the thesis's 30-frame window the rewards of a track grow with its
    length while the penalties where a wearer's detections switch to a bystander's are
    bounded (about window²/2 pairs): measured on held-out scenes, a wearer who left the view
    was replaced by a bystander whose pose fits the IMUs about as well. Trained with the
    other scales (`experiments/train_association.py`); the shipped weights use 30, chosen on
    development subjects (`experiments/vip_association_unseen.py`: 30 and 90 a detection apart).
  - Detections on different 2D tracks that share a frame are two people (`cross_tracks`,
    on by default): a wearer takes detections of at most one of any tracks that share a
    frame, a constraint of the binary program (`solve_labelling`), at any distance in time
    (their inter-frame pairs are dropped). Tracks (`detection_tracks`) link
    detections frame to frame by their keypoints, only where the link is unambiguous
    (people who overlap in the image end their tracks), so they err towards short. Measured
    on held-out scenes: a wearer who left the view was replaced by a bystander who had
    walked beside them, and f_trans cannot tell (the hand-held camera moves between the
    frames); a learned weight for the feature instead (logistic regression, jointly or on
    top of the thesis's four) was outweighed at long range by f_time's extrapolation.
  - Each assignment costs a trained `assignment_cost` on top of −log-odds, against a
    failure measured on held-out scenes (most wrong assignments there): a bystander's
    consistent track collects pair rewards of its own and a wearer who has left the view
    inherits it. The training grid picked 0: on the training scenes a positive cost lost
    recall and removed almost no wrong assignment.
  - Wearer exchanges (`solve_labelling`): the program is solved in chunks of 100 frames (the
    thesis solves one, with Gurobi), so the first chunk decides who is who without the later
    frames, and the wearers' 2D tracks and the pairs into decided frames carry that on. After
    the chunks, two wearers' assignments from a frame s on are exchanged wherever that lowers
    eq. 4.11 over the whole sequence (a move towards the one program's optimum; no new
    feature). Measured on held-out scene 51/5 (examined after its test): Inertial Tracker
    keypoints 26 cm (mean, root-relative) from the truth, hip-and-neck frames off by 29° and
    44° (x₀'s errors), fitted the other wearer's detections slightly better in frames 0-99
    (eq. 4.11 over them 31 lower exchanged, of −2640); one 2D track per wearer spans all 150
    frames, and the chunk's exchange held for the whole sequence (281 wrong, 0 right), whose
    objective is 532 lower exchanged back (frames 100-149: the wearers turn by 90° and 170°,
    and the inter-frame pairs of the exchanged hypotheses turn into penalties).
  - Identity check (`solve_labelling`, `AssociationModel.identity_margin`): after the program,
    a person may not keep a 2D track where another track's detection has the lower unary cost
    in more than half of its frames and by more than identity_margin log-odds a frame on
    average; the program is solved again without that person's hypotheses on it. Eq. 4.11's
    inter-frame pairs reward a consistent track whoever it is; only the unary says whose it is.
    Measured on an evaluation scene (2 bystanders, examined after its test): the wearer's
    detection had the best unary in 82 of 90 frames (about 2.5 a frame), and eq. 4.11's optimum
    (HiGHS: optimal) took 87 of a bystander's detections, whose steadier track's pair rewards
    (−1039.7 against −852.0) outweighed the unary sums (+64.0 against −155.9). On development
    scenes (subjects 02, 131, `experiments/vip_association_unseen.py --role development`; x₀
    30° off per joint makes them harder) a margin of 0 barred the wearer's right track in 2 of 26
    scenes (mean excess 0.33 and 0.02 a frame: Inertial Tracker keypoints that bad let a
    bystander fit a little better in most frames), 0.5-2 barred nothing; 1.0 is shipped
    (`experiments/results/vip_association_identity_dev.json`), between 0.33 and that evaluation
    scene's 2.5, so its set (seed 0) no longer measures the check: a fresh set (seed 1) does
    (`experiments/results/vip_association.md`). No development scene showed the
    failure above; one failed otherwise (x₀ 30° off: the bystander as likely by the unary, 88
    wrong with the check on or off): where the unary does not say whose a track is, it cannot.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
import scipy.sparse

from ..geometry.keypoints import COCO18_NAMES, flip_pairs
from ..rotation import axis_angle_to_matrix, matrix_to_axis_angle
from ..solve import Problem, Term, VonMarcardLM, frame, solve

__all__ = ["AssociationModel", "Association", "AssociationGraph", "HypothesisFeatures", "load_model", "associate",
           "association_graph", "solve_graph", "hypothesis_features", "pair_features", "solve_labelling", "camera_fit",
           "detection_tracks"]  # fmt: skip

WEIGHTS_FILE = Path(__file__).with_name("association_weights.json")
N_JOINTS = 18
_RHIP, _LHIP, _NECK = 8, 11, 1
MIN_KEYPOINTS = 5
_EPS = 1e-3  # ε of log(f + ε): 1 mm, 0.06°, 1e-3 normalised px·m
_MIN_DEPTH = 0.05  # m: a point behind the camera projects as if 5 cm in front
# HiGHS seconds per chunk: a safety net, not a budget. A chunk takes 5-30 s on an idle CPU;
# a limit that a loaded machine reaches returns HiGHS's incumbent, which measured far worse
# (recall 0.18-0.45 on 8 of 12 scenes at 30 s with 3 processes per core), so results would
# depend on the load. Reaching it warns.
TIME_LIMIT_S = 600.0
# HiGHS stops once its incumbent is within this fraction of the optimum's bound. HiGHS's
# own 1e-4 did not finish one held-out scene's first 100 frames (1150 hypotheses, 37,795
# pairs) in 10 minutes; 1e-2 took 4 minutes there and 1e-3 reached the same incumbent
# when its time ran out: the bound, not the labelling, is what converges slowly.
MIP_REL_GAP = 1e-2


@dataclasses.dataclass(frozen=True)
class AssociationModel:
    """Logistic-regression weights α (bias first) of the three feature kinds, the pair cost
    scale, the pruning threshold and the cost of each assignment (a decision threshold on
    the log-odds, chosen with pair_scale on the training scenes); `provenance` says how
    they were trained."""

    unary: tuple = (2.0, -1.0)
    inter: tuple = (2.0, -0.5, -0.5, -1.0)
    intra: tuple = (2.0, -0.5, -0.5)
    pair_scale: float = 0.1
    min_probability: float = 0.01
    assignment_cost: float = 0.0
    penalty_window: int = 30
    cross_tracks: bool = True
    identity_margin: float | None = None
    provenance: dict = dataclasses.field(default_factory=dict)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @property
    def tag(self) -> str:
        """A short name of the weights for result caches: "pw<penalty_window>", and with
        cross_tracks a hash of the weights (a result of another model is never reused)."""
        if not self.cross_tracks:
            return f"pw{self.penalty_window}"
        solver = {"cross_tracks_form": "frame cliques", "mip_rel_gap": MIP_REL_GAP, "exchange": "suffixes"}
        w = {k: v for k, v in self.to_dict().items() if k != "provenance"} | solver
        if self.identity_margin is None:  # models without the identity check keep their tags
            w.pop("identity_margin")
        return f"pw{self.penalty_window}_{hashlib.sha1(json.dumps(w, sort_keys=True).encode()).hexdigest()[:6]}"


def load_model(path=None) -> AssociationModel:
    """The shipped weights (`association_weights.json`) or those in `path`."""
    d = json.loads(Path(path or WEIGHTS_FILE).read_text())
    return AssociationModel(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


@dataclasses.dataclass(frozen=True)
class Association:
    """index (P, T): the assigned detection slot or −1; keypoints (P, T, 18, 3) the assigned
    rows (zero confidence where unassigned); objective: eq. 4.11 at the solution; status:
    one HiGHS message per chunk, then one line per wearer exchange (`solve_labelling`);
    seconds: {features, solve}."""

    index: np.ndarray
    keypoints: np.ndarray
    objective: float
    status: tuple
    seconds: dict


# ----------------------------------------------------------------------------- camera fit


def _translation(R, X, uv, w, group, G):
    """Least-squares t_g with R fixed: x̂ × (R X + t) = 0 per point (linear in t)."""
    xh = jnp.concatenate([uv, jnp.ones_like(uv[:, :1])], -1)
    A = jnp.cross(xh[:, None, :], jnp.eye(3)[None], axis=-1)  # [x̂]_× e_i columns
    A = jnp.swapaxes(A, -1, -2)  # (N, 3, 3) = [x̂]_×
    AtA = jnp.einsum("nji,njk->nik", A, A) * w[:, None, None]
    b = -jnp.einsum("nik,nk->ni", AtA, X @ R.T)
    one = jax.nn.one_hot(group, G)  # (N, G)
    M = jnp.einsum("ng,nik->gik", one, AtA) + 1e-9 * jnp.eye(3)
    return jnp.linalg.solve(M, jnp.einsum("ng,ni->gi", one, b)[..., None])[..., 0]


def _dlt_rotation(X, uv, w):
    """World-to-camera rotation from a weighted DLT (used when no camera IMU is given)."""
    Xh = jnp.concatenate([X, jnp.ones_like(X[:, :1])], -1)
    z = jnp.zeros_like(Xh)
    rows = jnp.concatenate([
        jnp.concatenate([Xh, z, -uv[:, :1] * Xh], -1), jnp.concatenate([z, Xh, -uv[:, 1:] * Xh], -1)], 0)  # fmt: skip
    rows = rows * jnp.sqrt(jnp.concatenate([w, w]))[:, None]
    Pm = jnp.linalg.svd(rows)[2][-1].reshape(3, 4)
    depth = (Xh @ Pm[2]) @ w  # points must lie in front
    Pm = jnp.where(depth < 0, -Pm, Pm)
    U, _, Vt = jnp.linalg.svd(Pm[:, :3])
    R = U @ Vt
    return jnp.where(jnp.linalg.det(R) < 0, -R, R)


def _reprojection(x, data):
    """√w_k (π(R X_k + t_g(k)) − uv_k), (1, N, 2): the camera fit's residual (eq. 4.13's e_k)."""
    R = x["rot"][0] if "rot" in x else data["R0"]
    q = data["X"] @ R.T + x["trans"][0][data["group"]]
    return (data["sw"][:, None] * (q[:, :2] / jnp.maximum(q[:, 2:], _MIN_DEPTH) - data["uv"]))[None]


#: The camera fit as an engine problem: one "frame" holding the pose, the rotation on SO(3)
#: (left-perturbed, as the LM's own) or, measured by the camera IMU, fixed in the data.
_CAMERA_FIT = {
    True: Problem([Term("reprojection", _reprojection)], {"rot": frame("so3"), "trans": frame()}),
    False: Problem([Term("reprojection", _reprojection)], {"trans": frame()}),
}


def camera_fit(X, uv, w, R0, group, num_groups: int, free_rotation: bool = True, max_steps: int = 30):
    """World-to-camera pose from 2D points: least squares by `jaxmocap.solve` (LM).

    X (N, 3) world points, uv (N, 2) normalised image points (K⁻¹ applied), w (N,)
    confidences (0 = absent), R0 (3, 3) start rotation, group (N,) the translation each
    point uses (0 .. num_groups−1; eq. 4.18's meta camera with unknown positions has two);
    free_rotation=False keeps R = R0 (a rotation measured by the camera IMU). The
    translations start at their linear least-squares values for R0. Marquardt damping
    (eq. 2.54: the rotation in radians and the translation in metres share no scale).
    Returns R (3, 3), t (num_groups, 3), per-point error ‖e_k‖ (N,), depth ‖R X + t‖ (N,)
    and the solve's result code (0: converged).
    """
    data = {"X": X, "uv": uv, "sw": jnp.sqrt(w), "group": group, "R0": R0}
    p0 = {"trans": _translation(R0, X, uv, w, group, num_groups)[None]}
    if free_rotation:
        p0["rot"] = matrix_to_axis_angle(R0)[None]
    sol = solve(_CAMERA_FIT[free_rotation], p0, data, max_steps=max_steps, solver=VonMarcardLM(damping="marquardt"))
    R = axis_angle_to_matrix(sol.value["rot"][0]) if free_rotation else R0
    t = sol.value["trans"][0]
    q = X @ R.T + t[group]
    err = jnp.linalg.norm(q[:, :2] / jnp.maximum(q[:, 2:], _MIN_DEPTH) - uv, axis=-1)
    return R, t, err, jnp.linalg.norm(q, axis=-1), sol.result


@functools.partial(jax.jit, static_argnames=("use_imu",))
def _unary_fits(X, uv, w, R_imu, use_imu: bool):
    def one(X, uv, w, R_imu):
        R0 = R_imu if use_imu else _dlt_rotation(X, uv, w)
        return camera_fit(X, uv, w, R0, jnp.zeros(len(X), int), 1, free_rotation=not use_imu)

    return jax.vmap(one)(X, uv, w, R_imu)


@functools.partial(jax.jit, static_argnames=("shared", "free_rotation"))
def _meta_fits(X, uv, w, R0, shared: bool, free_rotation: bool):
    group = jnp.zeros(X.shape[1], int) if shared else jnp.repeat(jnp.arange(2), N_JOINTS)
    fit = functools.partial(camera_fit, group=group, num_groups=1 if shared else 2, free_rotation=free_rotation)
    return jax.vmap(lambda X, uv, w, R0: fit(X, uv, w, R0))(X, uv, w, R0)


#: Rows per call of a batched camera fit: every call has this shape, so each variant compiles
#: once whatever the number of hypotheses (padded power-of-two sizes compiled one program per
#: size: ~3 CPU-s each); a block of 256 camera fits runs in ~40 ms here.
_BLOCK = 256


def _batched(fn, arrays, **kw):
    """fn over the leading axis in blocks of `_BLOCK` rows, the last one padded."""
    n = len(arrays[0])
    if n == 0:
        return None
    parts = []
    for start in range(0, n, _BLOCK):
        block = [a[start : start + _BLOCK] for a in arrays]
        m = len(block[0])
        pad = [np.concatenate([a, np.repeat(a[:1], _BLOCK - m, 0)]) for a in block]
        parts.append([np.asarray(o)[:m] for o in fn(*map(jnp.asarray, pad), **kw)])
    return [np.concatenate(outs) for outs in zip(*parts)]


# ----------------------------------------------------------------------------- features


def _check(joints3d, K, cam_orientation, detections):
    joints3d, detections = np.asarray(joints3d, np.float64), np.asarray(detections, np.float64)
    if joints3d.ndim != 4 or joints3d.shape[2:] != (N_JOINTS, 3):
        raise ValueError(f"joints3d has shape {joints3d.shape}; expected (P, T, 18, 3) world COCO-18 keypoints.")
    P, T = joints3d.shape[:2]
    if detections.ndim != 4 or detections.shape[0] != T or detections.shape[2:] != (N_JOINTS, 3):
        raise ValueError(f"detections have shape {detections.shape}; expected (T, D, 18, 3) rows "
                         f"(u, v, confidence) with T = {T} as in joints3d.")  # fmt: skip
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K has shape {K.shape}; expected (3, 3).")
    if cam_orientation is not None:
        cam_orientation = np.asarray(cam_orientation, np.float64)
        if cam_orientation.shape != (T, 3, 3):
            raise ValueError(f"cam_orientation has shape {cam_orientation.shape}; expected (T, 3, 3) = ({T}, 3, 3).")
        if not np.isfinite(cam_orientation).all():
            raise ValueError("cam_orientation has NaN samples; fill them or pass None.")
    return joints3d, K, cam_orientation, detections


@dataclasses.dataclass(frozen=True)
class HypothesisFeatures:
    """Per hypothesis (l, t, v) (P, T, D): valid, f_un (eq. 4.14), the camera R, t and the
    camera-frame root position (eq. 4.15) and orientation (eq. 4.16)."""

    valid: np.ndarray
    f_un: np.ndarray
    R: np.ndarray
    t: np.ndarray
    root: np.ndarray
    frame: np.ndarray


def _root_frames(X):
    """Mid-hip r_t and the body frame R_t (columns: hip line, up, forward) of (..., 18, 3)."""
    r = 0.5 * (X[..., _RHIP, :] + X[..., _LHIP, :])
    a = X[..., _LHIP, :] - X[..., _RHIP, :]
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    up = X[..., _NECK, :] - r
    up = up - (up * a).sum(-1, keepdims=True) * a
    up = up / np.linalg.norm(up, axis=-1, keepdims=True)
    return r, np.stack([a, up, np.cross(a, up)], -1)


def _normalised(detections, K):
    finite = np.isfinite(detections).all(-1)
    det = np.where(finite[..., None], detections, 0.0)
    w = np.clip(det[..., 2], 0.0, None)
    uv = (det[..., :2] - K[:2, 2]) @ np.linalg.inv(K[:2, :2]).T
    return uv, w


def hypothesis_features(joints3d, K, cam_orientation, detections) -> HypothesisFeatures:
    """Unary features of every hypothesis (eq. 4.13-4.14); arguments as in `associate`."""
    joints3d, K, cam_orientation, detections = _check(joints3d, K, cam_orientation, detections)
    P, T = joints3d.shape[:2]
    D = detections.shape[1]
    uv, w = _normalised(detections, K)
    valid = (
        np.broadcast_to(((w > 0).sum(-1) >= MIN_KEYPOINTS)[None], (P, T, D))
        & np.isfinite(joints3d).all((-1, -2))[:, :, None]
    )
    l, t, v = np.nonzero(valid)
    R_imu = np.eye(3)[None].repeat(T, 0) if cam_orientation is None else np.swapaxes(cam_orientation, -1, -2)
    f_un = np.full((P, T, D), np.inf)
    Rs, ts = np.zeros((P, T, D, 3, 3)), np.zeros((P, T, D, 3))
    out = _batched(_unary_fits, [joints3d[l, t], uv[t, v], w[t, v], R_imu[t]], use_imu=cam_orientation is not None)
    if out is not None:
        R, tt, err, depth, _ = out
        ww = w[t, v]
        e_img = (ww * err).sum(-1) / ww.sum(-1)  # eq. 4.13 (ours: / Σ w_k)
        e_cam = depth.mean(-1)  # mean distance of the 3D keypoints to the camera centre
        f_un[l, t, v] = np.where(np.isfinite(e_img * e_cam), e_img * e_cam, np.inf)
        Rs[l, t, v], ts[l, t, v] = R, tt[:, 0]
    r, B = _root_frames(np.nan_to_num(joints3d))
    root = np.einsum("ltdab,ltb->ltda", Rs, r) + ts
    frame = np.einsum("ltdab,ltbc->ltdac", Rs, B)
    return HypothesisFeatures(valid, f_un, Rs, ts, root, frame)


def detection_tracks(detections, link_distance: float = 0.15, ambiguity: float = 0.5, max_gap: int = 5):
    """2D tracks: detections linked to the tracks seen in the last `max_gap` frames by their keypoints.

    The distance of a detection to a track is the median keypoint offset from the track's
    last detection (left and right as labelled or exchanged, whichever is nearer: detectors
    swap them) over the keypoints both have, in units of that detection's size (box
    diagonal). A link needs distance <= link_distance × frames since the track was seen, and
    no rival (another detection for the track, another track for the detection) nearer
    than distance / ambiguity: people who overlap in the image end their tracks instead
    of swapping them, so a track errs towards short. Returns (track (T, D) ids, −1 where no
    detection; first (n,), last (n,) frame of each track).
    """
    det = np.asarray(detections, np.float64)
    T, D = det.shape[:2]
    seen = np.isfinite(det).all(-1) & (np.nan_to_num(det[..., 2]) > 0)
    xy = np.nan_to_num(det[..., :2])
    present = seen.sum(-1) >= 3
    swap = np.arange(N_JOINTS)
    for a, b in flip_pairs(COCO18_NAMES):
        swap[a], swap[b] = b, a
    track = np.full((T, D), -1)
    last_row, first, last = [], [], []  # per track: its latest (t, d), first and last frame
    for t in range(T):
        for gap in range(1, max_gap + 1):  # the tracks seen last frame first, then older ones
            cur = np.flatnonzero(present[t] & (track[t] < 0))
            live = [k for k in range(len(last)) if t - last[k] == gap]
            if not len(cur) or not live:
                continue
            dist = np.full((len(live), len(cur)), np.inf)
            for a, k in enumerate(live):
                tk, dk = last_row[k]
                size = np.linalg.norm(np.ptp(xy[tk, dk][seen[tk, dk]], 0)) + 1e-9
                for b, d in enumerate(cur):
                    for order in (slice(None), swap):
                        both = seen[tk, dk] & seen[t, d][order]
                        if both.sum() >= 3:
                            off = np.linalg.norm(xy[tk, dk][both] - xy[t, d][order][both], axis=-1)
                            dist[a, b] = min(dist[a, b], np.median(off) / size)
            for a, b in sorted(zip(*np.nonzero(dist <= link_distance * gap)), key=lambda ab: dist[ab]):
                rivals = np.r_[np.delete(dist[a], b), np.delete(dist[:, b], a)]
                if not (rivals < dist[a, b] / ambiguity).any() and track[t, cur[b]] < 0 and last[live[a]] < t:
                    k = live[a]
                    track[t, cur[b]] = k
                    last_row[k], last[k] = (t, cur[b]), t
        cur = np.flatnonzero(present[t])
        for d in cur[track[t, cur] < 0]:
            track[t, d] = len(last)
            last_row.append((t, d)), first.append(t), last.append(t)
    return track, np.asarray(first, int), np.asarray(last, int)


def _log(f):
    return np.log(np.asarray(f) + _EPS)


def unary_design(f_un):
    return np.stack([np.ones_like(f_un), _log(f_un)], -1)


def pair_features(
    hyp: HypothesisFeatures,
    keep,
    joints3d,
    K,
    detections,
    window: int = 30,
    positions_known: bool = False,
    imu_rotation: bool = True,
    tracks=None,
):
    """Inter- and intra-frame pairs among the kept hypotheses (keep (P, T, D) bool).

    Returns (inter, intra): inter {a, b: flat hypothesis indices into (P, T, D), f (n, 4)
    (f_trans, f_ori, f_time) eq. 4.15-4.17 and f_cross (1: the two detections lie on
    different `detection_tracks` that share a frame; `tracks`: theirs, if computed
    already)}; intra {a, b, f (m, 2)} eq. 4.18.
    """
    P, T, D = keep.shape
    flat = np.arange(P * T * D).reshape(P, T, D)
    A, B = [], []
    for l in range(P):  # eq. 4.15-4.17: same person, 0 < t' − t <= window
        t, v = np.nonzero(keep[l])
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        lo = np.searchsorted(t, t, side="right")
        hi = np.searchsorted(t, t + window, side="right")
        n = hi - lo
        i = np.repeat(np.arange(len(t)), n)
        j = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + np.repeat(lo, n)
        A.append(flat[l, t[i], v[i]])
        B.append(flat[l, t[j], v[j]])
    a, b = np.concatenate(A).astype(int), np.concatenate(B).astype(int)
    root, frame = hyp.root.reshape(-1, 3), hyp.frame.reshape(-1, 3, 3)
    f_trans = np.linalg.norm(root[a] - root[b], axis=-1)
    cos = (np.einsum("nab,nab->n", frame[a], frame[b]) - 1.0) / 2.0
    f_ori = np.arccos(np.clip(cos, -1.0, 1.0))
    _, ta, va = np.unravel_index(a, (P, T, D))
    _, tb, vb = np.unravel_index(b, (P, T, D))
    f_time = np.abs(ta - tb).astype(float)
    track, first, last = detection_tracks(detections) if tracks is None else tracks
    ka, kb = track[ta, va], track[tb, vb]
    f_cross = ((ka != kb) & (ka >= 0) & (kb >= 0) & (first[ka] <= last[kb]) & (first[kb] <= last[ka])).astype(float)
    inter = {"a": a, "b": b, "f": np.stack([f_trans, f_ori, f_time, f_cross], -1)}

    A, B = [], []
    for l in range(P):  # eq. 4.18: two people, one frame, two different detections
        for m in range(l + 1, P):
            both = keep[l][:, :, None] & keep[m][:, None, :] & ~np.eye(D, dtype=bool)
            t, v, u = np.nonzero(both)
            A.append(flat[l, t, v])
            B.append(flat[m, t, u])
    a = np.concatenate(A).astype(int) if A else np.zeros(0, int)
    b = np.concatenate(B).astype(int) if B else np.zeros(0, int)
    intra = {"a": a, "b": b, "f": np.zeros((len(a), 2))}
    if len(a):
        la, ta, va = np.unravel_index(a, (P, T, D))
        lb, _, vb = np.unravel_index(b, (P, T, D))
        uv, w = _normalised(np.asarray(detections, np.float64), K)
        X = np.concatenate([joints3d[la, ta], joints3d[lb, ta]], 1)
        R, tt, _, _, _ = _batched(_meta_fits, [X, np.concatenate([uv[ta, va], uv[ta, vb]], 1),
                                            np.concatenate([w[ta, va], w[ta, vb]], 1), hyp.R.reshape(-1, 3, 3)[a]],
                               shared=positions_known, free_rotation=not (positions_known and imu_rotation))  # fmt: skip
        centre = lambda R, t: -np.einsum("nba,nb->na", R, t)  # noqa: E731  c = −Rᵀ t
        Rf, tf = hyp.R.reshape(-1, 3, 3), hyp.t.reshape(-1, 3)
        f_a = np.linalg.norm(centre(Rf[a], tf[a]) - centre(R, tt[:, 0]), axis=-1)
        f_b = np.linalg.norm(centre(Rf[b], tf[b]) - centre(R, tt[:, -1]), axis=-1)
        intra["f"] = np.stack([f_a, f_b], -1)
    return inter, intra


def inter_design(f, window: int):
    return np.stack([np.ones(len(f)), _log(f[:, 0]), _log(f[:, 1]), f[:, 2] / window], -1)


def intra_design(f):
    return np.stack([np.ones(len(f)), _log(f[:, 0]), _log(f[:, 1])], -1)


# ----------------------------------------------------------------------------- labelling


def solve_labelling(
    shape,
    nodes,
    unary,
    pairs,
    pair_costs,
    chunk: int = 100,
    time_limit: float = TIME_LIMIT_S,
    tracks=None,
    mip_rel_gap: float = MIP_REL_GAP,
    identity_margin: float | None = None,
    max_rounds: int = 4,
):
    """Minimise eq. 4.11 subject to eq. 4.12 (`_solve_chunks`), then check every track a person
    took against the unary evidence (ours, needs `tracks`; None: no check).

    The identity check: for each person l and each 2D track k whose detections l took in frames
    S, the frames of S where another track's detection has a lower unary cost for l (more
    identity evidence: the thesis's unary is the only feature that says *whose* a detection
    is; the inter-frame pairs say that two detections are one person, whoever it is), and the
    mean excess over S of c_lv − min c_lv' (v' off track k; 0 where there is none). Where
    another track is better in more than half of S and the mean excess is above
    `identity_margin` (log-odds per frame), person l may not take track k, and the program is
    solved again without those hypotheses (at most `max_rounds` solves).
    Arguments and returns otherwise as `_solve_chunks`; status gains one line per barred track.
    """
    P, T, D = shape
    nodes = np.asarray(nodes, int)
    unary = np.asarray(unary, float)
    pairs = np.asarray(pairs, int).reshape(-1, 2)
    pair_costs = np.asarray(pair_costs, float)
    barred = np.zeros(P * T * D, bool)
    status = []
    rounds = max(1, max_rounds)
    for r in range(rounds):
        keep = ~barred[nodes]
        pk = ~(barred[pairs[:, 0]] | barred[pairs[:, 1]])
        chosen, objective, st = _solve_chunks(shape, nodes[keep], unary[keep], pairs[pk], pair_costs[pk], chunk,
                                              time_limit, tracks, mip_rel_gap)  # fmt: skip
        status += st
        if identity_margin is None or tracks is None or not len(chosen) or r == rounds - 1:
            break  # no check asked, or no solve left to act on what it finds
        bar, lines = _identity_check(shape, nodes[keep], unary[keep], chosen, np.asarray(tracks[0]), identity_margin)
        if not bar.any():
            break
        barred |= bar
        status += lines
    return chosen, objective, tuple(status)


def _identity_check(shape, nodes, unary, chosen, track, margin: float):
    """The hypotheses to bar: person l on every track k that `solve_labelling`'s identity check
    rejects (see there), as a flat (P·T·D,) mask, and one line per rejected (l, k)."""
    P, T, D = shape
    cost = np.full(P * T * D, np.inf)
    cost[nodes] = unary
    cost = cost.reshape(P, T, D)
    bar = np.zeros((P, T, D), bool)
    lines = []
    l_, t_, v_ = np.unravel_index(np.asarray(chosen, int), shape)
    for li in range(P):
        mine = l_ == li
        t, v = t_[mine], v_[mine]
        k = track[t, v]
        for kk in np.unique(k[k >= 0]):
            S, vs = t[k == kk], v[k == kk]
            other = np.where(track[S] != kk, cost[li, S], np.inf)  # (|S|, D): l's costs off track k
            excess = np.where(np.isfinite(other.min(1)), cost[li, S, vs] - other.min(1), 0.0)
            better = int((excess > 0).sum())
            if better > len(S) / 2 and excess.mean() > margin:
                bar[li] |= track == kk
                lines.append(f"identity check: person {li} may not take track {kk} ({len(S)} frames, another "
                             f"detection more likely in {better}, by {excess.sum():.1f} in all)")  # fmt: skip
    return bar.reshape(-1), lines


def _solve_chunks(
    shape,
    nodes,
    unary,
    pairs,
    pair_costs,
    chunk: int = 100,
    time_limit: float = TIME_LIMIT_S,
    tracks=None,
    mip_rel_gap: float = MIP_REL_GAP,
):
    """Minimise eq. 4.11 subject to eq. 4.12 with HiGHS, chunk frames at a time.

    shape (P, T, D); nodes: flat indices of the candidate hypotheses; unary: their costs
    c_v^l; pairs (m, 2) flat indices, pair_costs (m,) c_{v,v'}^{l,l'}; tracks: None or
    (track (T, D), first, last) of `detection_tracks`: then a person takes detections of at
    most one of any tracks that share a frame (cross_tracks); mip_rel_gap: HiGHS's
    relative optimality gap (`MIP_REL_GAP`). Returns the chosen flat indices, the
    objective and the HiGHS messages.

    Linearisation: y = x_a x_b is needed only on the side the objective pushes against,
    so y is continuous in [0, 1]: for c < 0 (a reward) y <= x_a, y <= x_b; for c > 0 (a
    penalty) y >= x_a + x_b − 1. At integral x the minimiser then sets y = x_a x_b exactly.
    Chunks: frames [s, s + chunk) are solved in order; pairs reaching back into decided
    chunks become linear terms on the new node (x_old is known), pairs to undecided later
    frames wait for their chunk. The first chunk ignores the future, a documented loss
    against one global program (which HiGHS needs minutes for at 300 frames × 5 × 2).
    Tracks: u_lk in [0, 1] says person l takes track k, x_lv <= u_l,track(v), and for
    every frame the u of the tracks there sum to <= 1 (tracks are intervals, so these
    frame cliques are all the conflicts, and their LP relaxation is tight: pair penalties
    of the same meaning made HiGHS hit its time limit). A track person l took in an
    earlier chunk keeps u_lk = 1.
    Then the whole sequence's objective is lowered by exchanging two people's assignments from
    a frame on (`_exchange_wearers`), where that helps: the chunks decide who is who from the
    past alone. status: one HiGHS message per chunk, then one line per exchange.
    """
    P, T, D = shape
    track_of, span0, span1 = (
        (np.full(P * T * D, -1), np.zeros(0, int), np.zeros(0, int))
        if tracks is None
        else (
            np.broadcast_to(np.asarray(tracks[0])[None], shape).reshape(-1),
            np.asarray(tracks[1]),
            np.asarray(tracks[2]),
        )
    )
    taken = [set() for _ in range(P)]
    nodes = np.asarray(nodes, int)
    frame_of = lambda f: np.unravel_index(f, shape)[1]  # noqa: E731
    chosen = np.zeros(P * T * D, bool)
    cost = np.zeros(P * T * D)
    cost[nodes] = unary
    pairs = np.asarray(pairs, int).reshape(-1, 2)
    pair_costs = np.asarray(pair_costs, float)
    pf = np.stack([frame_of(pairs[:, 0]), frame_of(pairs[:, 1])], -1) if len(pairs) else np.zeros((0, 2), int)
    objective, status = 0.0, []
    node_frame = frame_of(nodes)
    for s in range(0, T, chunk):
        e = min(T, s + chunk)
        here = nodes[(node_frame >= s) & (node_frame < e)]
        if len(here) == 0:
            continue
        c = cost[here].copy()
        pos = np.full(P * T * D, -1)
        pos[here] = np.arange(len(here))
        # pairs with one end decided before s: a linear term on the new end if the old was chosen
        back = (pf.min(1) < s) & (pf.max(1) >= s) & (pf.max(1) < e)
        pb, first = pairs[back], pf[back, 0] < s
        old, new = np.where(first, pb[:, 0], pb[:, 1]), np.where(first, pb[:, 1], pb[:, 0])
        on = chosen[old] & (pos[new] >= 0)
        np.add.at(c, pos[new[on]], pair_costs[back][on])
        inside = (pf.min(1) >= s) & (pf.max(1) < e)
        pi, pc = pairs[inside], pair_costs[inside]
        n, m = len(here), len(pi)
        ia, ib = pos[pi[:, 0]], pos[pi[:, 1]]
        rows, cols, vals, ub = [], [], [], []
        r = 0
        l_, t_, v_ = np.unravel_index(here, shape)
        for key in (t_ * D + v_, l_ * T + t_):  # eq. 4.12a (one person per detection), 4.12b
            _, g = np.unique(key, return_inverse=True)
            rows.append(r + g), cols.append(np.arange(n)), vals.append(np.ones(n))
            ub.append(np.ones(g.max() + 1))
            r += g.max() + 1
        neg = pc < 0
        k = np.flatnonzero(neg)  # y − x_a <= 0, y − x_b <= 0
        for x in (ia[k], ib[k]):
            rows += [r + np.arange(len(k))] * 2
            cols += [n + k, x]
            vals += [np.ones(len(k)), -np.ones(len(k))]
            ub.append(np.zeros(len(k)))
            r += len(k)
        k = np.flatnonzero(~neg)  # x_a + x_b − y <= 1
        rows += [r + np.arange(len(k))] * 3
        cols += [ia[k], ib[k], n + k]
        vals += [np.ones(len(k)), np.ones(len(k)), -np.ones(len(k))]
        ub.append(np.ones(len(k)))
        r += len(k)
        lb_u, nu = [], n + m
        for li in range(P):  # cross_tracks: u per (person, track), frame cliques
            mine = np.flatnonzero((l_ == li) & (track_of[here] >= 0))
            ks = sorted(set(track_of[here[mine]].tolist()) | taken[li])
            if not ks:
                continue
            col = dict(zip(ks, nu + np.arange(len(ks))))
            rows += [r + np.arange(len(mine))] * 2  # x_lv − u_lk <= 0
            cols += [mine, np.array([col[k] for k in track_of[here[mine]]], int)]
            vals += [np.ones(len(mine)), -np.ones(len(mine))]
            ub.append(np.zeros(len(mine)))
            r += len(mine)
            kk = np.array(ks)
            cliques = {tuple(kk[(span0[kk] <= span0[k]) & (span0[k] <= span1[kk])]) for k in ks}
            for q in (q for q in cliques if len(q) > 1):
                (
                    rows.append(np.full(len(q), r)),
                    cols.append(np.array([col[k] for k in q])),
                    vals.append(np.ones(len(q))),
                )
                ub.append(np.ones(1))
                r += 1
            lb_u += [1.0 if k in taken[li] else 0.0 for k in ks]
            nu += len(ks)
        A = scipy.sparse.csr_array((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r, nu))
        res = scipy.optimize.milp(
            np.concatenate([c, pc, np.zeros(nu - n - m)]), integrality=np.r_[np.ones(n), np.zeros(nu - n)],
            bounds=scipy.optimize.Bounds(np.r_[np.zeros(n + m), lb_u], 1),
            constraints=scipy.optimize.LinearConstraint(A, -np.inf, np.concatenate(ub)),
            options={"time_limit": time_limit, "mip_rel_gap": mip_rel_gap},
        )  # fmt: skip
        status.append(res.message)
        if "time limit" in str(res.message).lower():
            warnings.warn(
                f"association: HiGHS stopped at its time limit ({time_limit} s) on frames {s}-{e - 1}; "
                "the labelling there is its best so far, not the optimum: raise time_limit or "
                "use a smaller chunk",
                RuntimeWarning,
                stacklevel=2,
            )
        if res.x is None:  # no feasible point within the limit: leave the chunk unassigned
            continue
        pick = here[res.x[:n] > 0.5]
        chosen[pick] = True
        for li, k in zip(np.unravel_index(pick, shape)[0], track_of[pick]):
            if k >= 0:
                taken[li].add(int(k))
        objective += float(res.fun)
    if P > 1 and len(nodes):  # the chunks saw the past only: held-out scene 51/5's first chunk exchanged
        # its wearers (eq. 4.11 31 lower over frames 0-99), 532 higher over all 150 frames
        is_node = np.zeros(P * T * D, bool)
        is_node[nodes] = True
        chosen, gain, moves = _exchange_wearers(shape, cost, pairs, pair_costs, chosen, is_node, track_of, span0,
                                                span1)  # fmt: skip
        objective += gain
        status += moves
    return np.flatnonzero(chosen), objective, tuple(status)


def _exchange_wearers(shape, cost, pairs, pair_costs, chosen, is_node, track_of, span0, span1, max_moves: int = 100):
    """Local search on eq. 4.11 over the whole sequence after the chunks: exchange two people's
    assignments in frames [s, T) (every pair of people, every s) while the best such exchange
    lowers the objective. An exchanged hypothesis that is not a node is dropped; an exchange that
    leaves a person on two tracks that share a frame (cross_tracks) is not feasible.
    Returns chosen, the objective's change (<= 0) and one line per exchange.

    The change of every s at once, O(pairs + T): with Z the labelling exchanged in every frame,
    a pair of frames t <= t' is as in Z for s <= t, as in X (the labelling) for s > t', and
    has its frame-t end from X and its frame-t' end from Z in between."""
    P, T, D = shape
    person, frame = np.unravel_index(np.arange(P * T * D), shape)[:2]
    ta, tb = frame[pairs[:, 0]], frame[pairs[:, 1]]
    early = np.where(ta <= tb, pairs[:, 0], pairs[:, 1])
    late = np.where(ta <= tb, pairs[:, 1], pairs[:, 0])
    t0, t1 = np.minimum(ta, tb), np.maximum(ta, tb)

    def value(c):
        return cost[c].sum() + pair_costs[c[pairs[:, 0]] & c[pairs[:, 1]]].sum()

    def feasible(c, people):
        for li in people:
            ks = np.unique(track_of[c & (person == li)])
            ks = ks[ks >= 0]
            both = (span0[ks][:, None] <= span1[ks][None]) & (span0[ks][None] <= span1[ks][:, None])
            if both.sum() > len(ks):  # two tracks of one person share a frame
                return False
        return True

    def exchanged(X, li, m, s):
        Y = X.reshape(P, T, D).copy()
        Y[[li, m], s:] = Y[[m, li], s:]
        return Y.reshape(-1) & is_node

    current, gain, moves = value(chosen), 0.0, []
    for _ in range(max_moves):
        best = None
        for li in range(P):
            for m in range(li + 1, P):
                Z = exchanged(chosen, li, m, 0)
                un = np.zeros(T + 1)  # un[s]: the unary change of frames >= s
                np.add.at(un, frame, cost * Z - cost * chosen)  # cost is 0 off the nodes
                un = np.cumsum(un[::-1])[::-1]
                on_x, on_z = (pair_costs * (c[early] & c[late]) for c in (chosen, Z))
                on_xz = pair_costs * (chosen[early] & Z[late])
                d = np.zeros(T + 1)  # difference array over s: Z for s <= t, mixed for t < s <= t', X after
                d[0] = (on_z - on_x).sum()
                np.add.at(d, t0 + 1, on_xz - on_z)
                np.add.at(d, t1 + 1, on_x - on_xz)
                change = un[:T] + np.cumsum(d)[:T]
                for s in np.argsort(change, kind="stable"):
                    if change[s] >= -1e-9 * (1.0 + abs(current)) or (best is not None and change[s] >= best[0]):
                        break
                    c = exchanged(chosen, li, m, s)
                    if feasible(c, (li, m)):
                        best = (change[s], c, li, m, s)
                        break
        if best is None:
            break
        _, chosen, li, m, s = best
        v = value(chosen)
        moves.append(f"exchanged people {li} and {m} in frames {s}-{T - 1}: objective {current:.1f} -> {v:.1f}")
        gain += v - current
        current = v
    return chosen, gain, moves


def _logit(design, alpha):
    return design @ np.asarray(alpha, np.float64)


@dataclasses.dataclass(frozen=True)
class AssociationGraph:
    """The binary program of eq. 4.11 before the model's scales: candidate hypotheses
    `nodes` (flat (P, T, D) indices) with their unary log-odds `z`, `pairs` (m, 2) with their
    log-odds `pair_z` (inter-frame, then intra-frame); `seconds` the feature time."""

    shape: tuple
    nodes: np.ndarray
    z: np.ndarray
    pairs: np.ndarray
    pair_z: np.ndarray
    seconds: float
    tracks: tuple | None = None  # `detection_tracks` when cross_tracks (solve_labelling's constraint)


def association_graph(
    joints3d,
    K,
    cam_orientation,
    detections,
    model: AssociationModel | None = None,
    window: int = 30,
    positions_known: bool = False,
) -> AssociationGraph:
    """Features and log-odds of every hypothesis and pair (arguments as in `associate`)."""
    joints3d, K, cam_orientation, detections = _check(joints3d, K, cam_orientation, detections)
    if not (isinstance(window, (int, np.integer)) and window >= 1):
        raise ValueError(f"window must be an int >= 1, got {window!r}.")
    model = load_model() if model is None else model
    t0 = time.perf_counter()
    hyp = hypothesis_features(joints3d, K, cam_orientation, detections)
    z = np.where(hyp.valid, _logit(unary_design(np.where(hyp.valid, hyp.f_un, 1.0)), model.unary), -np.inf)
    keep = hyp.valid & (z >= np.log(model.min_probability / (1 - model.min_probability)))
    tracks = detection_tracks(detections)
    inter, intra = pair_features(hyp, keep, joints3d, K, detections, max(window, model.penalty_window),
                                 positions_known, cam_orientation is not None, tracks)  # fmt: skip
    inter_z = _logit(inter_design(inter["f"], window), model.inter)
    near = (inter["f"][:, 2] <= window) | (inter_z < 0)  # beyond the window: penalties only
    if model.cross_tracks:  # two people for certain: solve_labelling's track constraint, not a pair
        near &= inter["f"][:, 3] == 0
    pairs = np.concatenate([np.stack([inter["a"][near], inter["b"][near]], -1), np.stack([intra["a"], intra["b"]], -1)])
    pair_z = np.concatenate([inter_z[near], _logit(intra_design(intra["f"]), model.intra)])
    nodes = np.flatnonzero(keep)
    return AssociationGraph(keep.shape, nodes, z.reshape(-1)[nodes], pairs, pair_z, time.perf_counter() - t0,
                            tracks if model.cross_tracks else None)  # fmt: skip


def _check_chunk(chunk):
    if not (isinstance(chunk, (int, np.integer)) and chunk >= 1):
        raise ValueError(f"chunk must be an int >= 1, got {chunk!r}.")


def solve_graph(
    graph: AssociationGraph,
    detections,
    model: AssociationModel | None = None,
    chunk: int = 100,
    time_limit: float = TIME_LIMIT_S,
) -> Association:
    """Eq. 4.11 on `graph` with the model's costs: c_v = −z_v + assignment_cost (ours: a
    threshold on the evidence a detection needs), c_vv' = −pair_scale · z_vv'."""
    _check_chunk(chunk)
    model = load_model() if model is None else model
    P, T, D = graph.shape
    t1 = time.perf_counter()
    chosen, objective, status = solve_labelling(graph.shape, graph.nodes, model.assignment_cost - graph.z, graph.pairs,
                                                -model.pair_scale * graph.pair_z, chunk, time_limit, graph.tracks,
                                                identity_margin=model.identity_margin)  # fmt: skip
    index = np.full((P, T), -1)
    l, t, v = np.unravel_index(chosen, graph.shape)
    index[l, t] = v
    keypoints = np.zeros((P, T, N_JOINTS, 3))
    if D:
        detections = np.asarray(detections, np.float64)
        rows = np.nan_to_num(detections[np.arange(T)[None], np.maximum(index, 0)])
        keypoints = np.where((index >= 0)[..., None, None], rows, 0.0)
    return Association(index, keypoints, objective, status,
                       {"features": graph.seconds, "solve": time.perf_counter() - t1})  # fmt: skip


def associate(
    joints3d,
    K,
    cam_orientation,
    detections,
    model: AssociationModel | None = None,
    window: int = 30,
    positions_known: bool = False,
    chunk: int = 100,
    time_limit: float = TIME_LIMIT_S,
) -> Association:
    """Assign 2D detections to the P IMU wearers (eq. 4.11-4.18).

    Args:
        joints3d: (P, T, 18, 3) world COCO-18 keypoints of each wearer's hypothesis pose
            (e.g. the Inertial Tracker's through `geometry.keypoints.regress_keypoints`).
        K: (3, 3) intrinsics; cam_orientation: (T, 3, 3) camera-to-world rotation from the
            camera IMU, or None (each hypothesis camera then starts from a DLT).
        detections: (T, D, 18, 3) rows (u, v, confidence) in pixels; padded or missing rows
            have confidence 0 or NaN (NaN keypoints count as missing).
        model: `AssociationModel` (default: the shipped weights); window: inter-frame edges
            span at most this many frames (§4.4.1: 30); positions_known: the hypotheses
            share one world frame with their true relative positions (e.g. a fused result),
            so eq. 4.18's meta camera has one translation.
        chunk, time_limit: frames per binary program and HiGHS seconds per chunk (a safety
            net, `TIME_LIMIT_S`; reaching it warns).
    Returns:
        `Association`.
    """
    _check_chunk(chunk)  # before the features, which take seconds
    model = load_model() if model is None else model
    graph = association_graph(joints3d, K, cam_orientation, detections, model, window, positions_known)
    return solve_graph(graph, detections, model, chunk, time_limit)
