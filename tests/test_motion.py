"""Motion files and retargeting: AMASS npz, ASF/AMC, BVH, retarget, resample, library, errors."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxmocap
from jaxmocap.body import SMPL_JOINT_NAMES, SMPL_PARENTS, make_body
from jaxmocap.motion import (
    Motion,
    MotionFileError,
    SkeletonMotion,
    library,
    load_amass,
    load_asf_amc,
    load_bvh,
    load_motion,
    read_asf,
    retarget,
    save_amass,
    save_motion,
)
from jaxmocap.motion.amass import Z_UP_TO_Y_UP
from jaxmocap.motion.retarget import (
    CMU_ASF_MAP,
    CMU_BVH_MAP,
    MIXAMO_MAP,
    detect_rig,
    rest_kind,
    smpl_joint_positions,
    smpl_rest,
    strip_namespace,
)

CMU = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cmu"
needs_cmu = pytest.mark.skipif(not (CMU / "02.asf").is_file(), reason="needs ../shared/data/cmu")
CC = CMU.parent / "cmu_cc"
needs_cc = pytest.mark.skipif(not (CC / "007_02.bvh").is_file(), reason="needs ../shared/data/cmu_cc")
N = {n: i for i, n in enumerate(SMPL_JOINT_NAMES)}
ASF_UNIT = 0.0254 / 0.45


@pytest.fixture(scope="module")
def smpl_like_body():
    """A small random SMPL-layout body whose rest joints are SMPL's (approximately).

    Vertices 0..23 sit on the joints and the regressor picks them; two sole vertices at
    y = -1.16; the rest is random. Random shape blend shapes make j0 depend on betas.
    """
    rng = np.random.default_rng(0)
    extra = 30
    V = 24 + extra
    v = np.concatenate([library.SMPL_APPROX_REST, rng.normal(scale=0.3, size=(extra, 3))])
    v[24:, 1] = np.clip(v[24:, 1], -1.1, 0.6)
    v[24:26, 1] = -1.16
    w = np.zeros((V, 24))
    w[np.arange(24), np.arange(24)] = 1.0
    w[24:] = rng.random((extra, 24)) ** 4
    w[24:] /= w[24:].sum(1, keepdims=True)
    Jr = np.zeros((24, V))
    Jr[:, :24] = np.eye(24)
    return make_body(
        v,
        rng.integers(0, V, size=(V, 3)),
        rng.normal(scale=0.01, size=(V, 3, 10)),
        rng.normal(scale=0.01, size=(V, 3, 207)),
        Jr,
        w,
        dtype=np.float64,
    )


def random_motion(T=5, hands=False, seed=0, nb=10):
    rng = np.random.default_rng(seed)
    poses = rng.normal(scale=0.4, size=(T, 24, 3))
    if not hands:
        poses[:, 22:] = 0
    return Motion(
        poses,
        rng.normal(size=(T, 3)),
        fps=60.0,
        betas=rng.normal(size=nb),
        gender="female",
        name="r",
    )


# ---------------------------------------------------------------- AMASS


def write_amass(path, T=4, width=156, nb=10, seed=1, **over):
    rng = np.random.default_rng(seed)
    d = {
        "poses": rng.normal(scale=0.4, size=(T, width)),
        "trans": rng.normal(size=(T, 3)),
        "betas": rng.normal(size=nb),
        "gender": np.array(b"male"),
        "mocap_framerate": np.array(120.0),
    }
    d.update(over)
    d = {k: v for k, v in d.items() if v is not None}
    np.savez(path, **d)
    return d


@pytest.mark.parametrize("width", [156, 72, 165])
def test_amass_load_layouts_and_round_trip(tmp_path, random_body, width):
    d = write_amass(tmp_path / "a.npz", width=width)
    m = load_amass(tmp_path / "a.npz", body=random_body)
    assert m.poses.shape == (4, 24, 3) and m.fps == 120.0 and m.gender == "male"
    np.testing.assert_allclose(m.betas, d["betas"])
    np.testing.assert_allclose(m.poses[:, 1:22], d["poses"][:, 3:66].reshape(4, 21, 3))
    if width == 72:
        np.testing.assert_allclose(m.poses[:, 22:], d["poses"][:, 66:72].reshape(4, 2, 3))
    else:  # SMPL-H / SMPL-X: SMPL's hand joints are set to zero
        assert np.all(m.poses[:, 22:] == 0)
    save_amass(m, tmp_path / "b.npz", body=random_body)
    m2 = load_amass(tmp_path / "b.npz", body=random_body)
    np.testing.assert_allclose(m2.poses, m.poses, atol=1e-12)
    np.testing.assert_allclose(m2.trans, m.trans, atol=1e-12)
    with np.load(tmp_path / "b.npz") as f:
        assert f["poses"].shape == (4, 72 if width == 72 else 156)
        np.testing.assert_allclose(f["trans"], d["trans"], atol=1e-12)  # save undoes load


@pytest.mark.parametrize("hands", [False, True])
def test_save_load_amass_is_identity(tmp_path, random_body, hands):
    m = random_motion(hands=hands)
    save_amass(m, tmp_path / "m.npz", body=random_body)
    m2 = load_amass(tmp_path / "m.npz", body=random_body)
    np.testing.assert_allclose(m2.poses, m.poses, atol=1e-12)
    np.testing.assert_allclose(m2.trans, m.trans, atol=1e-12)
    assert (m2.fps, m2.gender) == (m.fps, m.gender)
    np.testing.assert_allclose(m2.betas, m.betas)
    m3 = load_amass(save_amass(m, tmp_path / "d.npz"))  # default pivot: also identity
    np.testing.assert_allclose(m3.poses, m.poses, atol=1e-12)
    np.testing.assert_allclose(m3.trans, m.trans, atol=1e-12)


def test_amass_z_up_conversion_rotates_the_posed_mesh(tmp_path, random_body):
    """Mesh(converted motion) == R · Mesh(AMASS values): checks the pelvis-pivot correction."""
    d = write_amass(tmp_path / "a.npz", T=3, width=156, seed=3)
    m = load_amass(tmp_path / "a.npz", body=random_body)
    pose_amass = np.zeros((3, 24, 3))
    pose_amass[:, :22] = d["poses"][:, :66].reshape(3, 22, 3)
    ref = jaxmocap.forward(random_body, pose_amass, d["betas"], d["trans"])
    out = jaxmocap.forward(random_body, m.poses, m.betas, m.trans)
    R = Z_UP_TO_Y_UP
    np.testing.assert_allclose(out.vertices, np.asarray(ref.vertices) @ R.T, atol=1e-10)
    np.testing.assert_allclose(out.joints[:, 0], np.asarray(ref.joints[:, 0]) @ R.T, atol=1e-10)
    np.testing.assert_allclose(out.joint_rotations[:, 0], R @ np.asarray(ref.joint_rotations[:, 0]), atol=1e-10)
    # z up became y up: a point straight above in AMASS is straight above here.
    np.testing.assert_allclose(R @ [0, 0, 1], [0, 1, 0])


def test_amass_errors(tmp_path):
    write_amass(tmp_path / "nokey.npz", trans=None)
    with pytest.raises(MotionFileError, match=r"nokey\.npz.*trans"):
        load_amass(tmp_path / "nokey.npz")
    write_amass(tmp_path / "norate.npz", mocap_framerate=None)
    with pytest.raises(MotionFileError, match="mocap_framerate"):
        load_amass(tmp_path / "norate.npz")
    np.savez(tmp_path / "noposes.npz", betas=np.zeros(10))
    with pytest.raises(MotionFileError, match=r"noposes\.npz.*poses"):
        load_amass(tmp_path / "noposes.npz")
    write_amass(tmp_path / "shape.npz", poses=np.zeros((4, 50)))
    with pytest.raises(MotionFileError, match=r"shape\.npz.*\(4, 50\)"):
        load_amass(tmp_path / "shape.npz")
    write_amass(tmp_path / "tshape.npz", trans=np.zeros((3, 3)))
    with pytest.raises(MotionFileError, match="trans has shape"):
        load_amass(tmp_path / "tshape.npz")
    nan = np.zeros((4, 156))
    nan[1, 5] = np.nan
    write_amass(tmp_path / "nan.npz", poses=nan)
    with pytest.raises(MotionFileError, match=r"nan\.npz.*NaN"):
        load_amass(tmp_path / "nan.npz")
    (tmp_path / "junk.npz").write_text("not a zip")
    with pytest.raises(MotionFileError, match=r"junk\.npz"):
        load_amass(tmp_path / "junk.npz")
    with pytest.raises(FileNotFoundError, match=r"missing\.npz"):
        load_amass(tmp_path / "missing.npz")


def test_own_npz_format_and_dispatch(tmp_path, random_body):
    m = random_motion(hands=True)
    save_motion(m, tmp_path / "own.npz")
    m2 = load_motion(tmp_path / "own.npz")
    np.testing.assert_array_equal(m2.poses, m.poses)
    np.testing.assert_array_equal(m2.trans, m.trans)
    assert (m2.fps, m2.gender, m2.name) == (m.fps, m.gender, m.name)
    save_amass(m, tmp_path / "amass.npz", body=random_body)
    m3 = load_motion(tmp_path / "amass.npz", body=random_body)  # AMASS path: converted back
    np.testing.assert_allclose(m3.trans, m.trans, atol=1e-12)


# ---------------------------------------------------------------- ASF / AMC

SMALL_ASF = """\
# two bones
:version 1.10
:name test
:units
  mass 1.0
  length 0.45
  angle deg
:documentation
  hand written
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name upper
     direction 1 0 0
     length 4.5
     axis 0 0 90  XYZ
    dof rx ry rz
    limits (-160.0 20.0)
           (-70.0 70.0)
           (-60.0 70.0)
  end
  begin
     id 2
     name lower
     direction 0 -1 0
     length 9
     axis 0 0 0 XYZ
    dof rx
    limits (-10.0 170.0)
  end
:hierarchy
  begin
    root upper
    upper lower
  end
"""

SMALL_AMC = """\
#!OML:ASF test.asf
:FULLY-SPECIFIED
:DEGREES
1
root 10 20 30 0 90 0
upper 0 0 0
lower 90
2
root 0 0 0 0 0 0
upper 90 0 0
lower 0
3
root 0 0 0 90 90 0
upper 0 0 0
lower 0
"""


@pytest.fixture()
def small_asf(tmp_path):
    (tmp_path / "07.asf").write_text(SMALL_ASF)
    (tmp_path / "07_01.amc").write_text(SMALL_AMC)
    return tmp_path


def test_small_asf_amc_closed_form(small_asf):
    s = read_asf(small_asf / "07.asf")
    assert s.length_unit == pytest.approx(ASF_UNIT)
    assert [b.name for b in s.bones] == ["upper", "lower"] and s.bone("upper").limits[0] == (
        -160,
        20,
    )
    m = load_asf_amc(small_asf / "07_01.amc")  # finds 07.asf next to it
    assert m.names == ("root", "upper", "lower") and m.fps == 120.0 and m.num_frames == 3
    a, b = 4.5 * ASF_UNIT, 9 * ASF_UNIT
    end = m.end_positions()
    root1 = np.array([10, 20, 30]) * ASF_UNIT
    # Frame 1: root Ry(90) maps x→−z; lower: Ry(90)·Rx(90) maps −y → −x.
    np.testing.assert_allclose(m.positions[0, 0], root1, atol=1e-12)
    np.testing.assert_allclose(m.positions[0, 2], root1 + [0, 0, -a], atol=1e-12)
    np.testing.assert_allclose(end[0, 2], root1 + [-b, 0, -a], atol=1e-12)
    # Frame 2: upper rx=90 in the axis frame C=Rz(90) is a 90° turn about world y.
    np.testing.assert_allclose(m.rotations[1, 1], Rotation.from_euler("y", 90, degrees=True).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(end[1, 2], [0, -b, -a], atol=1e-12)
    # Frame 3: root RX=90 RY=90 about fixed axes, X first: R = Ry(90)·Rx(90).
    np.testing.assert_allclose(m.positions[2, 2], [0, 0, -a], atol=1e-12)
    np.testing.assert_allclose(end[2, 2], [-b, 0, -a], atol=1e-12)


def test_amc_errors(small_asf):
    lines = SMALL_AMC.splitlines()
    (small_asf / "07_02.amc").write_text("\n".join(lines[:-1]) + "\n")  # last frame cut
    with pytest.raises(MotionFileError, match=r"07_02\.amc, line 12.*frame 3.*lower.*truncated"):
        load_asf_amc(small_asf / "07_02.amc")
    (small_asf / "07_03.amc").write_text(SMALL_AMC.replace("lower 90", "lower x9"))
    with pytest.raises(MotionFileError, match=r"07_03\.amc, line 7: non-numeric"):
        load_motion(small_asf / "07_03.amc")
    (small_asf / "07_04.amc").write_text(SMALL_AMC.replace("lower 90", "lower 90 1"))
    with pytest.raises(MotionFileError, match=r"line 7: expected 1 numbers"):
        load_asf_amc(small_asf / "07_04.amc")
    (small_asf / "99_01.amc").write_text(SMALL_AMC)
    (small_asf / "08.asf").write_text(SMALL_ASF)  # two skeletons, none called 99.asf
    with pytest.raises(FileNotFoundError, match=r"99_01\.amc.*99\.asf"):
        load_motion(small_asf / "99_01.amc")
    m = load_asf_amc(small_asf / "99_01.amc", asf_path=small_asf / "08.asf")
    assert m.num_frames == 3


def test_load_motion_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothing\.bvh"):
        load_motion(tmp_path / "nothing.bvh")
    (tmp_path / "clip.xyz").write_text("1 2 3")
    with pytest.raises(MotionFileError, match=r"clip\.xyz"):
        load_motion(tmp_path / "clip.xyz")
    (tmp_path / "bad.bvh").write_text("not a bvh")
    with pytest.raises(MotionFileError, match=r"bad\.bvh.*HIERARCHY"):
        load_motion(tmp_path / "bad.bvh")


@needs_cmu
def test_cmu_asf_amc():
    s = read_asf(CMU / "02.asf")
    assert s.bone("lfemur").length * s.length_unit == pytest.approx(0.43, abs=0.005)
    m = load_asf_amc(CMU / "02_01.amc")
    assert m.num_frames == 343 and m.fps == 120.0 and len(m.names) == 31
    end = m.end_positions()
    assert 0.85 < m.positions[:, 0, 1].mean() < 1.05  # pelvis (root) height
    toes = end[:, [m.index("ltoes"), m.index("rtoes")], 1]
    assert -0.03 < toes.min() < 0.05  # toes touch the floor
    assert 1.45 < end[:, m.index("head"), 1].mean() < 1.75
    # Rest pose faces +z with the left side at +x (SMPL's frame).
    assert m.rest_positions[m.index("lfemur"), 0] > 0.05 and m.tips[m.index("lfoot"), 2] > 0


# ---------------------------------------------------------------- BVH

SMALL_BVH = """\
HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Knee
\t{
\t\tOFFSET 0 -10 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -10 0
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 0.02
0 100 0 0 0 0 0 0 0
5 100 0 90 0 0 0 90 0
0 100 0 90 90 0 0 0 0
"""


def test_small_bvh_closed_form(tmp_path):
    (tmp_path / "s.bvh").write_text(SMALL_BVH)
    m = load_bvh(tmp_path / "s.bvh", scale=0.01)
    assert m.names == ("Hips", "Knee", "Knee_end") and m.fps == 50.0 and m.num_frames == 3
    np.testing.assert_allclose(m.positions[0], [[0, 1, 0], [0, 0.9, 0], [0, 0.8, 0]], atol=1e-12)
    # Frame 2: Hips Rz(90) maps −y → +x; the knee's Rx(90) maps −y → −z.
    np.testing.assert_allclose(m.positions[1], [[0.05, 1, 0], [0.15, 1, 0], [0.15, 1, -0.1]], atol=1e-12)
    # Frame 3: channels Z X Y compose about moving axes: R = Rz(90)·Rx(90), −y → −z.
    np.testing.assert_allclose(m.positions[2, 1], [0, 1, -0.1], atol=1e-12)
    np.testing.assert_allclose(m.tips[1], [0, -0.1, 0])
    (tmp_path / "t.bvh").write_text(SMALL_BVH[: SMALL_BVH.rindex("0 100 0 90 90")] + "0 100 0 90\n")
    with pytest.raises(MotionFileError, match=r"t\.bvh.*3 frames.*only 2"):
        load_bvh(tmp_path / "t.bvh")
    (tmp_path / "u.bvh").write_text(SMALL_BVH.replace("5 100", "5 abc"))
    with pytest.raises(MotionFileError, match=r"u\.bvh, line 20: non-numeric"):
        load_bvh(tmp_path / "u.bvh")


@needs_cmu
def test_cmu_bvh():
    m = load_bvh(CMU / "131_01.bvh")  # scale="auto" picks the ASF unit
    assert m.num_frames == 994 and m.fps == 120.0
    assert 0.9 < m.positions[0, 0, 1] < 1.0
    toes = m.positions[:, [m.index("LeftToe_end"), m.index("RightToe_end")], 1]
    assert -0.05 < toes.min() < 0.05
    m2 = load_bvh(CMU / "131_01.bvh", scale=ASF_UNIT)
    np.testing.assert_array_equal(m.positions, m2.positions)


# ---------------------------------------------------------------- retargeting


def smpl_world(motion, body):
    out = jaxmocap.forward(body, motion.poses, None, motion.trans)
    return np.asarray(out.joints)


def direction_errors(joints, src, table):
    """Mean angle (degrees) between SMPL bone p→j and source point(p)→point(j), per bone."""
    point = {k: v if isinstance(v, str) else v[1] for k, v in table.items()}
    errors = {}
    for j in range(1, 24):
        p = SMPL_PARENTS[j]
        a = joints[:, j] - joints[:, p]
        s = (
            src.positions[:, src.index(point[SMPL_JOINT_NAMES[j]])]
            - src.positions[:, src.index(point[SMPL_JOINT_NAMES[p]])]
        )
        if np.linalg.norm(s[0]) < 1e-6:
            continue
        cos = np.sum(a * s, 1) / np.linalg.norm(a, axis=1) / np.linalg.norm(s, axis=1)
        errors[(SMPL_JOINT_NAMES[p], SMPL_JOINT_NAMES[j])] = np.degrees(np.arccos(np.clip(cos, -1, 1))).mean()
    return errors


def test_retarget_same_skeleton_reproduces_positions(smpl_like_body):
    """A source with SMPL's own rest joints: the retargeted body reproduces its joints."""
    rng = np.random.default_rng(4)
    rest, _ = smpl_rest(smpl_like_body)
    T = 3
    local = Rotation.from_rotvec(rng.normal(scale=0.5, size=(T * 24, 3))).as_matrix().reshape(T, 24, 3, 3)
    G = local.copy()
    for j in range(1, 24):
        G[:, j] = G[:, SMPL_PARENTS[j]] @ local[:, j]
    root = rng.normal(size=(T, 3))
    pos = smpl_joint_positions(G, rest, root - rest[0])
    src = SkeletonMotion(SMPL_JOINT_NAMES, SMPL_PARENTS, rest - rest[0], np.zeros((24, 3)), G, pos, 30.0, "synthetic")
    m = retarget(src, body=smpl_like_body, mapping={n: n for n in SMPL_JOINT_NAMES}, floor=False)
    np.testing.assert_allclose(smpl_world(m, smpl_like_body), pos, atol=1e-9)
    np.testing.assert_allclose(
        Rotation.from_rotvec(m.poses.reshape(-1, 3)).as_matrix(), local.reshape(-1, 3, 3), atol=1e-9
    )


@needs_cmu
def test_retarget_cmu_walk(smpl_like_body):
    src = load_asf_amc(CMU / "02_01.amc")
    m = retarget(src, body=smpl_like_body)
    assert m.num_frames == 343 and m.fps == 120.0
    assert np.isfinite(m.poses).all() and np.isfinite(m.trans).all()
    joints = smpl_world(m, smpl_like_body)
    pelvis = joints[:, 0]
    assert 0.8 < pelvis[:, 1].mean() < 1.0  # soles at y = 0
    speed = np.linalg.norm((pelvis[-1] - pelvis[0])[[0, 2]]) / m.duration
    assert 0.5 < speed < 2.0
    assert (pelvis[-1] - pelvis[0])[2] > 1.0  # walks toward +z, the way SMPL faces
    for knee in ("left_knee", "right_knee"):
        flexion = np.degrees(np.linalg.norm(m.poses[:, N[knee]], axis=1))
        assert 40 < flexion.max() - flexion.min() < 80
    ahead = joints[:, N["left_ankle"], 2] - joints[:, N["right_ankle"], 2]
    assert np.count_nonzero(np.diff(np.sign(ahead))) >= 2  # feet alternate
    feet = joints[:, [N["left_foot"], N["right_foot"]], 1]
    assert 0.0 < feet.min() < 0.05
    errors = direction_errors(joints, src, CMU_ASF_MAP)
    assert np.mean(list(errors.values())) < 10
    for bone in [
        ("left_hip", "left_knee"),
        ("right_knee", "right_ankle"),
        ("left_shoulder", "left_elbow"),
        ("spine1", "spine2"),
    ]:
        assert errors[bone] < 0.1  # aligned bones follow the source exactly


def _reframed(src, frames):
    """The same motion on a rig whose bone j carries the constant frame `frames[j]`.

    World positions stay; global rotations become G_j R_j, and the zero pose is rebuilt
    from the child offsets expressed in the new parent frames (as a BVH of that rig has).
    """
    R = np.asarray(frames)
    rest = np.zeros_like(src.rest_positions)
    for j, p in enumerate(src.parents):
        if p >= 0:
            rest[j] = rest[p] + R[p].T @ (src.rest_positions[j] - src.rest_positions[p])
    return dataclasses.replace(
        src, rest_positions=rest, tips=np.einsum("nba,nb->na", R, src.tips), rotations=src.rotations @ R
    )


def _write_bvh(path, names, parents, offsets, local, root_pos, extra_leaves=(), units=100.0):
    """A BVH file (ZYX Euler channels, `units` per metre) of local rotations (T, N, 3, 3).

    `extra_leaves` are (parent index, name) helper bones with random rotations: a rig's
    twist/"share" bones, which no map names and which must not change the result.
    """
    rng = np.random.default_rng(1)
    T, N = local.shape[:2]
    kids = {j: [c for c in range(N) if parents[c] == j] for j in range(N)}
    helpers = {j: [n for p, n in extra_leaves if p == j] for j in range(N)}
    lines, cols = ["HIERARCHY"], []

    def emit(j, depth):
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if parents[j] < 0 else 'JOINT'} {names[j]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET " + " ".join(f"{x * units:.6f}" for x in offsets[j]))
        chans = (["Xposition", "Yposition", "Zposition"] if parents[j] < 0 else []) + [
            "Zrotation",
            "Yrotation",
            "Xrotation",
        ]
        lines.append(f"{pad}  CHANNELS {len(chans)} " + " ".join(chans))
        if parents[j] < 0:
            cols.append(root_pos * units)
        cols.append(Rotation.from_matrix(local[:, j]).as_euler("ZYX", degrees=True))
        for c in kids[j]:
            emit(c, depth + 1)
        for h in helpers[j]:
            lines.extend([f"{pad}  JOINT {h}", pad + "  {", f"{pad}    OFFSET 0.0 0.0 0.0",
                      f"{pad}    CHANNELS 3 Zrotation Yrotation Xrotation", f"{pad}    End Site", pad + "    {",
                          f"{pad}      OFFSET 0.0 2.0 0.0", pad + "    }", pad + "  }"])  # fmt: skip
            cols.append(rng.uniform(-40, 40, size=(T, 3)))
        if not kids[j] and not helpers[j]:
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0.0 5.0 0.0", pad + "  }"])
        lines.append(pad + "}")

    emit(0, 0)
    values = np.concatenate(cols, axis=1)
    lines += ["MOTION", f"Frames: {T}", "Frame Time: 0.033333"]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in values]
    Path(path).write_text("\n".join(lines) + "\n")


MADE_UP = {n: f"rig:B{j:02d}" for j, n in enumerate(SMPL_JOINT_NAMES)}


def test_retarget_made_up_rig_from_a_bvh_file_with_a_toml_map(smpl_like_body, tmp_path):
    # Known answer: a rig with SMPL's rest skeleton under other names (with a namespace,
    # centimetres, helper bones) gives back the SMPL motion it was written from.
    rng = np.random.default_rng(7)
    rest, _ = smpl_rest(smpl_like_body)
    T = 4
    rotvec = rng.normal(scale=0.4, size=(T, 24, 3))
    local = Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_matrix().reshape(T, 24, 3, 3)
    offsets = np.array([rest[0] * 0] + [rest[j] - rest[SMPL_PARENTS[j]] for j in range(1, 24)])
    trans = rng.normal(scale=0.2, size=(T, 3)) + [0, 0.9, 0]
    names = [MADE_UP[n] for n in SMPL_JOINT_NAMES]
    helpers = [(N["left_hip"], "rig:ThighTwistL"), (N["right_knee"], "rig:KneeShareR")]
    path = tmp_path / "made_up.bvh"
    _write_bvh(path, names, SMPL_PARENTS, offsets, local, trans, helpers)
    table = tmp_path / "made_up.toml"
    table.write_text("[map]\n" + "".join(f'{k} = "{v.split(":")[1]}"\n' for k, v in MADE_UP.items()))
    m = load_motion(path, body=smpl_like_body, mapping=table, floor=False)
    np.testing.assert_allclose(
        Rotation.from_rotvec(m.poses.reshape(-1, 3)).as_matrix(), local.reshape(-1, 3, 3), atol=1e-5
    )
    np.testing.assert_allclose(m.trans, trans - rest[0], atol=1e-5)
    # An incomplete map names what is missing; a built-in name that does not fit fails clearly.
    table.write_text("".join(f'{k} = "{v.split(":")[1]}"\n' for k, v in MADE_UP.items() if "knee" not in k))
    with pytest.raises(ValueError, match=r"\['left_knee', 'right_knee'\] unmapped"):
        load_motion(path, body=smpl_like_body, mapping=table)
    with pytest.raises(ValueError, match="No built-in SMPL joint map"):
        load_motion(path, body=smpl_like_body)


def test_detect_rig_mixamo_with_namespace():
    names = tuple(f"mixamorig:{v}" for v in MIXAMO_MAP.values())
    src = SkeletonMotion(names, (-1,) * len(names), np.zeros((len(names), 3)), np.zeros((len(names), 3)),
                         np.tile(np.eye(3), (1, len(names), 1, 1)), np.zeros((1, len(names), 3)), 30.0, "x")  # fmt: skip
    assert detect_rig(strip_namespace(src))[0] == "mixamo"
    no_fingers = dataclasses.replace(src, names=tuple(n.replace("Middle1", "Stub") for n in src.names))
    assert detect_rig(strip_namespace(no_fingers))[0] == "mixamo"  # fingers are optional


@needs_cmu
def test_retarget_motion_rest_does_not_depend_on_bone_frames(smpl_like_body):
    # Rigs from animation tools give each bone its own frame (legs pointing up at zero).
    # In "motion" mode the SMPL poses are the same whatever frames the bones carry.
    src = load_asf_amc(CMU / "02_01.amc")
    frames = Rotation.random(len(src.names), random_state=3).as_matrix()
    a = retarget(src, body=smpl_like_body, rest="motion")
    b = retarget(_reframed(src, frames), body=smpl_like_body, rest="motion")
    np.testing.assert_allclose(
        Rotation.from_rotvec(a.poses.reshape(-1, 3)).as_matrix(),
        Rotation.from_rotvec(b.poses.reshape(-1, 3)).as_matrix(), atol=1e-6,
    )  # fmt: skip
    np.testing.assert_allclose(a.trans, b.trans, atol=1e-9)
    # A random rig is recognised as one whose zero pose is not a rest pose; CMU's is one.
    assert rest_kind(_reframed(src, frames), smpl_rest(smpl_like_body)[0], CMU_ASF_MAP) == "motion"
    assert rest_kind(src, smpl_rest(smpl_like_body)[0], CMU_ASF_MAP) == "zero"
    # The data-chosen twists keep the knee a hinge about SMPL's x axis where it bends.
    for knee in ("left_knee", "right_knee"):
        k = a.poses[:, N[knee]]
        bent = np.linalg.norm(k, axis=1) > np.radians(20)
        assert bent.sum() > 50 and (np.abs(k[bent, 0]) / np.linalg.norm(k[bent], axis=1)).mean() > 0.9


@needs_cc
def test_retarget_cc_rig_walk_is_anatomical(smpl_like_body):
    # The CC rig's zero pose has legs and arms pointing up; before the "motion" rest its
    # hips came out twisted by ~170°.
    m = load_motion(CC / "007_02.bvh", body=smpl_like_body)
    deg = np.degrees(np.linalg.norm(m.poses, axis=-1))
    for j in ("left_hip", "right_hip", "left_knee", "right_knee", "spine1", "spine2", "spine3", "neck"):
        assert deg[:, N[j]].max() < 75, (j, deg[:, N[j]].max())
    knee = m.poses[:, N["left_knee"]]
    assert 40 < np.degrees(knee[:, 0].max() - knee[:, 0].min()) < 90  # flexion about x
    assert np.degrees(np.linalg.norm(m.poses[:, 0] - m.poses[:1, 0], axis=-1)).max() < 60  # a straight walk
    joints = smpl_world(m, smpl_like_body)
    ahead = joints[:, N["left_ankle"], 2] - joints[:, N["right_ankle"], 2]
    assert np.count_nonzero(np.diff(np.sign(ahead))) >= 2  # feet alternate
    assert 0.8 < joints[:, 0, 1].mean() < 1.05  # pelvis at standing height, soles on the floor


@needs_cmu
def test_load_motion_cmu_resampled(smpl_like_body):
    m = load_motion(CMU / "02_01.amc", fps=30, body=smpl_like_body)
    assert m.fps == 30.0 and m.num_frames == 86
    b = load_motion(CMU / "131_01.bvh", body=smpl_like_body)
    assert b.num_frames == 994 and np.isfinite(b.poses).all()
    errors = direction_errors(smpl_world(b, smpl_like_body), load_bvh(CMU / "131_01.bvh"), CMU_BVH_MAP)
    assert np.mean(list(errors.values())) < 10


# ---------------------------------------------------------------- resampling


def test_resample_counts_and_exact_frames():
    T = 400
    t = np.arange(T) / 120.0
    poses = np.zeros((T, 24, 3))
    poses[:, 0, 1] = 0.5 * np.sin(t)
    poses[:, 5, 0] = t / 2
    m = Motion(poses, np.stack([t, 0 * t, t**2], -1), fps=120.0)
    r = m.resample(30)
    assert r.num_frames == 100 and r.fps == 30.0
    np.testing.assert_allclose(r.poses, m.poses[::4], atol=1e-10)
    np.testing.assert_allclose(r.trans, m.trans[::4], atol=1e-12)
    assert m.resample(120.0) is m


def test_slerp_midpoint():
    poses = np.zeros((2, 24, 3))
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    poses[1, 3] = 1.2 * axis
    poses[1, 0] = [0, np.pi * 0.9, 0]
    m = Motion(poses, [[0, 0, 0], [1, 2, 4]], fps=1.0)
    r = m.resample(2.0)
    assert r.num_frames == 3
    np.testing.assert_allclose(r.poses[1, 3], 0.6 * axis, atol=1e-12)
    np.testing.assert_allclose(r.poses[1, 0], [0, np.pi * 0.45, 0], atol=1e-12)
    np.testing.assert_allclose(r.trans[1], [0.5, 1, 2])


# ---------------------------------------------------------------- procedural library


def test_library_walk_is_a_plausible_periodic_gait(smpl_like_body):
    m = library.walk(num_frames=61, fps=30.0, frequency=1.0, body=smpl_like_body)
    assert m.poses.shape == (61, 24, 3) and m.fps == 30.0
    np.testing.assert_allclose(m.poses[30], m.poses[0], atol=1e-9)  # one stride = 1 s
    np.testing.assert_allclose(m.trans[30, :2], m.trans[0, :2], atol=1e-9)
    joints = smpl_world(m, smpl_like_body)
    speed = (joints[-1, 0, 2] - joints[0, 0, 2]) / m.duration
    assert 0.7 < speed < 1.6
    feet = [N["left_ankle"], N["right_ankle"], N["left_foot"], N["right_foot"]]
    above_sole = joints[:, feet, 1] - (library.SMPL_APPROX_REST[feet, 1] + 1.16)
    assert -0.01 < above_sole.min(1).max() < 0.02  # a heel or toe on the ground at all times
    knee = np.degrees(np.linalg.norm(m.poses[:, N["left_knee"]], axis=1))
    assert 45 < knee.max() - knee.min() < 70
    # right heel strike at t=0: right hip flexed (thigh forward), left extended.
    assert joints[0, N["right_knee"], 2] > joints[0, N["left_knee"], 2]


@pytest.mark.parametrize("name", sorted(library.MOTIONS))
def test_library_motions_are_finite_and_grounded(name, smpl_like_body):
    m = library.MOTIONS[name](num_frames=40, fps=20.0, body=smpl_like_body)
    assert m.num_frames == 40 and np.isfinite(m.poses).all()
    joints = smpl_world(m, smpl_like_body)
    assert -0.02 < joints[:, [7, 8, 10, 11], 1].min() < 0.1
