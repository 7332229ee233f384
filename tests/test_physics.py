"""Physical plausibility: MJX checker against MuJoCo C, metrics, energies, report, CLI.

One scene (low-res default body, a box object) is built per module; every `check` call
uses batches of B frames so the MJX kernel compiles once. The energies are engine terms
on rotation matrices: with the IMU terms in one problem, and rebuilt without retracing.
"""

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import trimesh

from conftest import assert_picture

from jaxmocap.body import default_body, forward, shaped_joints
from jaxmocap.energies.imu import InertialData, orientation_term
from jaxmocap.energies.posed import CombinedData
from jaxmocap.motion import save_motion
from jaxmocap.objects import ObjectSDF, RigidObject
from jaxmocap.physics import (
    Ground,
    check,
    detect_foot_contact,
    foot_skating,
    GroundSupportResidual,
    PhysicsData,
    ground_support_term,
    make_scene,
    object_penetration,
    penetration_summary,
    pose_bones,
)
from jaxmocap.body.model import SMPL_FEET
from jaxmocap.physics.metrics import bone_min_distance, foot_contact
from jaxmocap.priors import default_pose_prior
from jaxmocap.rotation import axis_angle_to_matrix, geodesic_angle, matrix_to_quaternion
from jaxmocap.solve import Problem, Term, solve

B = 8  # frames per check call (one compile)
TOL_C = 1e-9  # |MJX - MuJoCo C| plane-capsule distance, metres (float64 on both sides)
TOL_MESH = 1e-6  # capsule-mesh penetration depth, for the pairs where both pick the same feature
BOX = (0.3, 0.2, 0.3)  # extents of the test object, metres
FAR = np.array([0.0, -10.0, 5.0])  # where the box waits when a test does not need it


@pytest.fixture(scope="module")
def body():
    return default_body("low").astype(jnp.float64)


@pytest.fixture(scope="module")
def scene(body):
    box = RigidObject.from_trimesh(trimesh.creation.box(extents=BOX), "box")
    return make_scene(body, ground=Ground(-0.85), objects=[box])


def _check(scene, poses, trans, box_pos):
    n = len(poses)
    pad = lambda x: np.concatenate([x, np.repeat(x[-1:], B - n, 0)])  # noqa: E731
    out = check(
        scene,
        pad(np.asarray(poses, float)),
        pad(np.asarray(trans, float)),
        object_positions=pad(np.asarray(box_pos, float)).reshape(B, 1, 3),
    )
    return jax.tree.map(lambda x: np.asarray(x)[:n], out)


def _mujoco_c(scene, pose, trans, box_pos):
    """Minimum contact distance per geom pair from `mujoco.mj_forward` on the same MJCF."""
    m = scene.mj_model()
    d = mujoco.MjData(m)
    R, J = pose_bones(scene, jnp.asarray(pose), jnp.asarray(trans))
    bone = np.asarray(scene.geometry.bone)
    q = np.concatenate([np.asarray(J)[bone], np.asarray(matrix_to_quaternion(R[bone]))], 1)
    d.qpos[:] = np.concatenate([q.ravel(), box_pos, [1, 0, 0, 0]])
    mujoco.mj_forward(m, d)
    out = {}
    for dist, (g1, g2) in zip(d.contact.dist[: d.ncon], d.contact.geom[: d.ncon]):
        key = tuple(sorted(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in (g1, g2)))
        out[key] = min(out.get(key, np.inf), dist)
    return out


def test_mjcf_loads_in_mujoco(scene):
    m = scene.mj_model()
    K = scene.geometry.num_geoms
    assert m.ngeom == 1 + K + 1 and m.npair == K + K + 1  # ground, capsules, box part
    assert np.allclose(m.opt.gravity, [0, -9.81, 0])  # y up, kept as is
    assert (np.asarray(scene.geometry.fit_rms) < 0.03).all()


def test_mjx_matches_mujoco_c(scene):
    """Plane-capsule: every pair equal to C. Capsule-mesh (penetrating pairs): most equal
    to C; the rest differ where C's GJK/EPA and MJX's capsule-convex collider pick
    different contact features (deep or edge contacts; measured up to ~3 cm on 4x8
    random poses, 75 % of pairs within 1e-6 m), so only a majority is asserted."""
    rng = np.random.default_rng(1)
    poses = rng.normal(scale=0.4, size=(B, 24, 3))
    trans = rng.normal(scale=0.05, size=(B, 3))
    box = rng.normal(scale=0.1, size=(B, 3))  # the box overlaps the torso and arms
    out = _check(scene, poses, trans, box)
    mesh_errors = []
    for i in range(B):
        ref = _mujoco_c(scene, poses[i], trans[i], box[i])
        for k, name in enumerate(scene.geometry.name):
            # Plane-capsule: true signed distance, reported by C up to the 3 m margin.
            assert out.ground[i, k] == pytest.approx(ref[("ground", name)], abs=TOL_C)
            c = ref.get(tuple(sorted((name, "box_part0"))))
            if c is not None and out.obj[i, k, 0] < 0:
                mesh_errors.append(abs(out.obj[i, k, 0] - c))
    mesh_errors = np.array(mesh_errors)
    assert len(mesh_errors) > 10
    assert np.median(mesh_errors) < TOL_MESH and (mesh_errors < TOL_MESH).mean() > 0.6


def _standing(scene, d):
    """Zero pose with the lowest capsule exactly d below the floor."""
    pose = np.zeros((1, 24, 3))
    lowest = _check(scene, pose, np.zeros((1, 3)), FAR[None]).ground.min()
    return pose, np.array([[0.0, -lowest - d, 0.0]])


@pytest.mark.parametrize("d", [0.0, 0.01, 0.05])
def test_lowered_body_reports_penetration_d(scene, body, d):
    pose, trans = _standing(scene, d)
    out = _check(scene, pose, trans, FAR[None])
    assert -out.ground.min() == pytest.approx(d, abs=1e-9)
    assert penetration_summary(out.ground.min(-1))["penetration_max_mm"] == pytest.approx(1e3 * d, abs=1e-6)
    # The mesh: lowered by d from touching, every vertex height drops by exactly d.
    v0 = np.asarray(forward(body, pose[0], None, trans[0] + [0, d, 0]).vertices)
    v1 = np.asarray(forward(body, pose[0], None, trans[0]).vertices)
    h0, h1 = scene.ground.signed_distance(v0), scene.ground.signed_distance(v1)
    assert float(h0.min() - h1.min()) == pytest.approx(d, abs=1e-9)


def test_hand_in_box_reports_penetration_d(scene):
    d = 0.02
    pose = np.zeros((1, 24, 3))
    a, b, r = scene.geometry.capsule_segments(*pose_bones(scene, jnp.asarray(pose[0]), jnp.zeros(3)))
    k = scene.geometry.name.index("right_hand")
    centre = 0.5 * np.asarray(a[k] + b[k])
    bottom = min(float(a[k][1]), float(b[k][1])) - float(r[k])
    box_pos = np.array([[centre[0], bottom + d - BOX[1] / 2, centre[2]]])  # top face d above the hand's bottom
    out = _check(scene, pose, np.zeros((1, 3)), box_pos)
    assert -out.obj[0, k, 0] == pytest.approx(d, abs=1e-6)
    assert -out.obj[0, :, 0].min() == pytest.approx(d, abs=1e-6)  # the wrist may touch, less deep
    ref = _mujoco_c(scene, pose[0], np.zeros(3), box_pos[0])
    assert ref[("box_part0", "right_hand")] == pytest.approx(-d, abs=1e-6)


def test_planted_foot_zero_skating_sliding_foot_measured(scene):
    pose, trans = _standing(scene, 0.0)
    T, fps = B, 30.0
    poses, still = np.repeat(pose, T, 0), np.repeat(trans, T, 0)
    out = _check(scene, poses, still, np.tile(FAR, (T, 1)))
    heights = bone_min_distance(scene, out.ground, SMPL_FEET)
    contact = foot_contact(heights)
    assert contact.all()
    joints = np.stack([np.asarray(pose_bones(scene, jnp.asarray(p), jnp.asarray(t))[1]) for p, t in zip(poses, still)])
    feet = joints[:, [scene.joint_names.index(n) for n in SMPL_FEET]]
    assert np.nanmax(foot_skating(feet, contact, scene.ground, fps)) == pytest.approx(0.0, abs=1e-9)
    slide = feet + np.arange(T)[:, None, None] * np.array([0.5 / fps, 0, 0])  # 0.5 m/s along x
    assert np.nanmean(foot_skating(slide, contact, scene.ground, fps)) == pytest.approx(0.5, rel=1e-9)


def test_object_sdf_near_surface():
    mesh = trimesh.creation.box(extents=BOX)
    sdf = ObjectSDF.from_trimesh(mesh, resolution=24, padding=0.05)
    rng = np.random.default_rng(0)
    p = rng.uniform(-0.2, 0.2, size=(2000, 3))
    q = np.abs(p) - np.array(BOX) / 2
    exact = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)
    near = np.abs(exact) < 0.01
    # Trilinear interpolation is exact for a linear field: near a face (not an edge) it is.
    face = near & (np.sort(q, 1)[:, 1] < -0.03)
    assert np.abs(np.asarray(sdf(jnp.asarray(p))) - exact)[face].max() < 1e-6
    assert np.abs(np.asarray(sdf(jnp.asarray(p))) - exact)[near].max() < 0.01
    pen = object_penetration(jnp.asarray(p), sdf, jnp.eye(3), jnp.zeros(3))
    assert np.allclose(np.asarray(pen)[face], np.maximum(-exact[face], 0), atol=1e-6)
    # Gradients flow through the trilinear lookup: inside near a face they point outwards.
    g = np.asarray(jax.grad(lambda x: sdf(x).sum())(jnp.asarray(p[face])))
    q_face = q[face]
    normal = np.eye(3)[np.argmax(q_face, 1)] * np.sign(p[face])
    assert (np.sum(g * normal, 1) > 0.99).all()


def test_object_sdf_refuses_an_open_mesh_and_is_built_once():
    box = trimesh.creation.box(extents=BOX)
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)
    with pytest.raises(ValueError, match="not watertight.*fill_holes"):
        ObjectSDF.from_trimesh(open_box)
    obj = RigidObject.box(BOX)
    assert obj.sdf(resolution=8) is obj.sdf(resolution=8)
    assert len(obj.parts) == 1 and obj.parts[0][0].shape == (8, 3)  # a box is its own hull


def test_ground_residual_gradients_and_descent(body):
    ground = Ground(0.0)
    rng = np.random.default_rng(2)
    pose = rng.normal(scale=0.1, size=(1, 24, 3))
    rest = np.asarray(forward(body, pose, None, np.zeros((1, 3))).vertices)
    trans = np.zeros((1, 3))
    trans[:, 1] = -rest[..., 1].min(-1) - 0.05  # 5 cm below the floor
    params = {"pose": jnp.asarray(pose), "trans": jnp.asarray(trans)}
    term, data = GroundSupportResidual(), PhysicsData(body=body, ground=ground)

    def r(p):  # the term sees rotation matrices; differentiate w.r.t. axis-angle here
        return term({"pose": axis_angle_to_matrix(p["pose"]), "trans": p["trans"]}, data)

    flat = jax.jit(lambda p: r(p).ravel())
    eps = 1e-6

    @jax.jit
    def derivatives(p, v):  # one program, not one per derivative and eager op
        plus, minus = jax.tree.map(lambda x, y: x + eps * y, p, v), jax.tree.map(lambda x, y: x - eps * y, p, v)
        fd = (flat(plus) - flat(minus)) / (2 * eps)
        return jax.jacfwd(flat)(p), jax.jacrev(flat)(p), jax.jvp(flat, (p,), (v,))[1], fd

    # Finite differences along a random direction (away from the hinge's kinks).
    v = jax.tree.map(lambda x: jnp.asarray(rng.normal(size=x.shape)), params)
    jf, jr, jvp, fd = derivatives(params, v)
    for key in params:
        assert np.isfinite(np.asarray(jf[key])).all()
        np.testing.assert_allclose(np.asarray(jf[key]), np.asarray(jr[key]), atol=1e-10)
    np.testing.assert_allclose(np.asarray(jvp), np.asarray(fd), atol=1e-6)

    # A few Gauss-Newton steps on ½‖r‖² push the body up out of the floor.
    @jax.jit
    def step(p):
        x, unravel = jax.flatten_util.ravel_pytree(p)
        res = lambda x: flat(unravel(x))  # noqa: E731
        Jm = jax.jacfwd(res)(x)
        dx = jnp.linalg.solve(Jm.T @ Jm + 1e-3 * jnp.eye(len(x)), Jm.T @ res(x))
        return unravel(x - dx)

    before = float(np.max(np.asarray(flat(params))))
    for _ in range(5):
        params = step(params)
    assert before == pytest.approx(0.05, abs=1e-9)
    assert float(np.max(np.asarray(flat(params)))) < 1e-3


def test_foot_contact_detected_from_motion(body):
    from jaxmocap.motion import library

    walk = library.walk(num_frames=60, fps=30.0)
    joints = np.asarray(forward(body, walk.poses, None, walk.trans).joints)
    ids = [body.joint_index(n) for n in ("left_ankle", "right_ankle")]
    # The procedural walk's stance foot slides at 0.1-0.6 m/s (measured), hence 1 m/s here.
    ground = Ground(float(joints[:, ids, 1].min()) - 0.01)
    contact = jax.jit(lambda p: detect_foot_contact(p, ground, walk.fps, height=0.06, speed=1.0))  # one program
    w = np.asarray(contact(joints[:, ids]))
    assert w.shape == (59, 2)
    assert 0.2 < (w > 0.5).mean() < 0.9  # stance part of the gait cycle, not all or nothing
    assert ((w[:, 0] > 0.5) | (w[:, 1] > 0.5)).mean() > 0.7  # walking: mostly one foot down


def test_check_cli(tmp_path, capsys):
    from jaxmocap.cli import main
    from jaxmocap.motion import library

    walk = library.walk(num_frames=16, fps=30.0)
    path = save_motion(walk, tmp_path / "walk.npz")
    assert main(["check", str(path), "--ground", "auto", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "contact frames > 5 mm" in out and "skating speed" in out
    assert_picture(tmp_path / "out" / "walk_check.png", min_bytes=1000, min_colour_fraction=0.001)
    assert (tmp_path / "out" / "walk_contact_heatmap.ply").exists()


def test_batch_shapes(scene):
    poses = np.zeros((2, B // 2, 24, 3))
    out = check(scene, poses.reshape(B, 24, 3), np.zeros((B, 3)), object_positions=np.tile(FAR, (B, 1, 1)))
    out2 = check(scene, poses, np.zeros((2, B // 2, 3)), object_positions=np.tile(FAR, (2, B // 2, 1, 1)))
    assert out2.ground.shape == (2, B // 2, scene.geometry.num_geoms)
    np.testing.assert_allclose(np.asarray(out2.ground).reshape(B, -1), np.asarray(out.ground))
    with pytest.raises(ValueError, match="expected"):
        check(scene, np.zeros((B, 23, 3)), np.zeros((B, 3)))


def _stay(params, data):
    """Keep the translation near data["trans0"]: (T, 3)."""
    return params["trans"] - data["trans0"]


def test_ground_term_plugs_into_the_solve_engine():
    """The physics residuals are engine `Term`s on rotation matrices: LM lifts a sunk
    body out of the floor."""
    body = default_body("low")
    rest = np.asarray(forward(body, np.zeros((24, 3))).vertices)
    soles = np.argsort(rest[:, 1])[:40]  # the lowest vertices: the soles
    pose0 = jnp.asarray(np.zeros((2, 24, 3)))
    trans0 = jnp.asarray(np.tile([0.0, -rest[:, 1].min() - 0.03, 0.0], (2, 1)))  # 3 cm down
    R0 = jax.jit(axis_angle_to_matrix)(pose0)  # one program, not op by op
    data = CombinedData((PhysicsData(body=body, ground=Ground(0.0)), {"pose0": R0, "trans0": trans0}))

    def stay(p, d):
        return jnp.concatenate([(p["pose"] - d["pose0"]).reshape(2, -1), _stay(p, d)], -1)

    problem = Problem([ground_support_term(soles, weight=1e2), Term("stay", stay, weight=1e-2)], rotations=("pose",))
    sol = solve(problem, {"pose": pose0, "trans": trans0}, data, max_steps=20)
    lifted = np.asarray(forward(body, sol.value["pose"], None, sol.value["trans"]).vertices)
    assert lifted[:, soles, 1].min() > -1e-3  # was -30 mm
    assert np.isfinite(np.asarray(sol.cost)).all()


#: Trace count of `_CountingGround` (Python runs `__call__` only while JAX traces).
TRACES = [0]


class _CountingGround(GroundSupportResidual):
    def __call__(self, params, data):
        TRACES[0] += 1
        return super().__call__(params, data)


_IMU_BONES = tuple(range(24))  # a sensor on every bone: the orientations fix the pose


def _imu_ground(body, seed, sink):
    """Truth poses (3 frames), their bone orientations as IMU data, a floor `sink` m above
    the truth's lowest vertex (at trans 0), and a start at the zero pose."""
    rng = np.random.default_rng(seed)
    T = 3
    pose = jnp.asarray(rng.normal(scale=0.3, size=(T, 24, 3)))
    orientation, lowest, rest_joints = _truth(body, pose)
    S = len(_IMU_BONES)
    inertial = InertialData(
        orientation=orientation,
        acceleration=np.zeros((T, S, 3)),
        sensor_to_bone=np.broadcast_to(np.eye(3), (S, 3, 3)),
        sensor_point=np.zeros((S, 3)),
        rest_joints=rest_joints,
        prior=default_pose_prior(jnp.float64),
    )
    ground = Ground(float(lowest) + sink)
    trans0 = jnp.zeros((T, 3))
    data = CombinedData((inertial, PhysicsData(body=body, ground=ground), {"trans0": trans0}))
    problem = Problem([
        orientation_term(_IMU_BONES, w_ori=1.0),
        Term("ground", _CountingGround(), 1e2),
        Term("stay", _stay, 1e-4),
    ], rotations=("pose",))  # fmt: skip
    return problem, {"pose": jnp.zeros((T, 24, 3)), "trans": trans0}, data, pose


@eqx.filter_jit
def _truth(body, pose):
    """The IMU orientations, lowest vertex height and rest joints of `pose`: one program."""
    truth = forward(body, pose)
    return (
        truth.joint_rotations[:, list(_IMU_BONES)],
        truth.vertices[..., 1].min(),
        shaped_joints(body, jnp.zeros(body.num_betas)),
    )


@eqx.filter_jit
def _fit_arrays(body, params, data):
    out = forward(body, params["pose"], None, params["trans"])
    ori = geodesic_angle(out.joint_rotations[:, list(_IMU_BONES)], data.orientation).max()
    return ori, data.ground.signed_distance(out.vertices).min()


def _fit(body, params, data):
    """Largest orientation error (rad) and lowest vertex height above the floor (m)."""
    ori, height = _fit_arrays(body, params, data)  # one program, not op by op
    return float(ori), float(height)


@pytest.fixture(scope="module")
def body64():
    return default_body("low").astype(jnp.float64)


def test_imu_and_ground_terms_in_one_problem(body64):
    """E_ori (rotation matrices, `InertialData`) and ground support (posed vertices,
    `PhysicsData`) in ONE problem: the pose follows the IMUs, the body rises 3 cm."""
    problem, params0, data, truth = _imu_ground(body64, seed=0, sink=0.03)
    assert _fit(body64, params0, data)[0] > 0.5  # the start is far from the IMUs
    assert _fit(body64, {"pose": truth, "trans": params0["trans"]}, data)[1] == pytest.approx(-0.03)
    sol = solve(problem, params0, data, max_steps=30)
    ori, height = _fit(body64, sol.value, data)
    assert ori < 1e-3  # radians: the orientation term was minimised
    assert height > -1e-3  # metres: the ground term was too (the truth at trans 0: -30 mm)
    assert float(sol.costs["ori"]) < 1e-6 and float(sol.costs["ground"]) < 1e-6


def test_rebuilt_problem_with_new_data_does_not_retrace(body64):
    """A new `Problem` with equal term configurations and new data of the same shapes
    (other poses, other floor height) reuses the compiled solve: no term is retraced."""
    problem, params0, data, _ = _imu_ground(body64, seed=0, sink=0.03)
    solve(problem, params0, data, max_steps=30)
    traced = TRACES[0]
    assert traced > 0
    problem, params0, data, _ = _imu_ground(body64, seed=1, sink=0.05)
    sol = solve(problem, params0, data, max_steps=30)
    assert TRACES[0] == traced
    ori, height = _fit(body64, sol.value, data)  # and the new data were used
    assert ori < 1e-3 and height > -1e-3
    # The frame holding the truth's lowest vertex rose by the 5 cm the floor rose.
    assert float(sol.value["trans"][:, 1].max()) == pytest.approx(0.05, abs=2e-3)


def test_mjx_ground_term_on_rotation_matrices(scene):
    """The MJX variant reads the scene as data and rotation matrices as the pose: it
    equals the checker's plane-capsule penetration, with forward-mode derivatives."""
    from jaxmocap.physics import MJXGroundResidual

    pose, trans = _standing(scene, 0.02)
    poses, trans = np.repeat(pose, B, 0), jnp.asarray(np.repeat(trans, B, 0))
    R = jax.jit(axis_angle_to_matrix)(jnp.asarray(poses))  # one program, not op by op
    data = PhysicsData(scene=scene)

    def f(t):
        return MJXGroundResidual()({"pose": R, "trans": t}, data)[..., 0]

    up = jnp.asarray(np.tile([0.0, 1.0, 0.0], (B, 1)))
    r, dr = eqx.filter_jit(lambda t: jax.jvp(f, (t,), (up,)))(trans)
    expected = np.maximum(-_check(scene, poses, trans, np.tile(FAR, (B, 1))).ground, 0.0)
    np.testing.assert_allclose(np.asarray(r), expected, atol=1e-9)
    assert float(np.asarray(r).max()) == pytest.approx(0.02, abs=1e-9)
    sunk = np.asarray(r) > 1e-6
    assert sunk.any() and np.allclose(np.asarray(dr)[sunk], -1.0)
    assert np.allclose(np.asarray(dr)[~sunk], 0.0)


def test_physics_terms_share_one_posed_body(body64):
    """Ground, foot-contact and object terms read one posed body per evaluation, the
    problem's (`Term.posed`), and give the same residuals as each computing its own."""
    from jaxmocap.energies.posed import PosedBody
    from jaxmocap.physics import FootStationarityResidual, ObjectPenetrationResidual

    calls = []

    class Counted(eqx.Module):
        def __call__(self, params, data):
            calls.append(1)
            return PosedBody()(params, data)

    T = 3
    rng = np.random.default_rng(4)
    pose = axis_angle_to_matrix(jnp.asarray(rng.normal(scale=0.2, size=(T, 24, 3))))
    params = {"pose": pose, "trans": jnp.zeros((T, 3))}
    sdf = ObjectSDF.from_trimesh(trimesh.creation.box(extents=BOX), resolution=8)
    data = PhysicsData(
        body=body64, ground=Ground(-0.8), contact_weights=jnp.ones((T - 1, 4)), sdf=sdf,
        object_rotation=jnp.broadcast_to(jnp.eye(3), (T, 3, 3)), object_position=jnp.zeros((T, 3)),
    )  # fmt: skip
    fns = [GroundSupportResidual(), FootStationarityResidual(), ObjectPenetrationResidual(margin=0.01)]
    terms = [Term(f"t{i}", f, bandwidth=int(i == 1), posed=PosedBody()) for i, f in enumerate(fns)]
    problem = Problem(terms + [Term("stay", lambda p, d: p["trans"][:, None])], rotations=("pose",), posed=Counted())
    out = problem.residuals_on_manifold(params, data)
    assert len(calls) == 1
    problem.residuals_on_manifold(params, data, names=("stay",))
    assert len(calls) == 1  # no term of these reads it: not computed
    raw = [f(params, data) for f in fns]  # on its own, a residual poses the body itself
    for i, r in enumerate(raw):
        kept = r if i != 1 else r.at[0].set(0.0).at[-1].set(0.0)  # the bandwidth-1 term's edge rows are dropped
        np.testing.assert_array_equal(np.asarray(out[f"t{i}"]), np.asarray(kept).reshape(T, -1))
    V = body64.num_vertices
    assert [r.shape for r in raw] == [(T, V, 1), (T, 4, 3), (T, V, 1)]
    assert float(raw[2].max()) > 0.05  # the box sits in the torso
    assert float(jnp.abs(raw[1][-1]).max()) == 0.0  # padding row
    with pytest.raises(ValueError, match="different posed bodies"):
        Problem(terms + [Term("other", fns[0], posed=Counted())], rotations=("pose",))


def test_check_plot_title_is_the_file_name_and_the_legend_beside_the_curve(tmp_path):
    """A synthetic report (no MJX): the title had the absolute path, the legend sat on the curve."""
    from matplotlib.figure import Figure

    from jaxmocap.physics.report import PlausibilityReport, plot_report

    T = 30
    lowest = 0.01 * np.sin(np.linspace(0, 6, T))
    report = PlausibilityReport(
        name="/very/long/absolute/folder/02_01.amc", fps=30.0, ground_height=0.0, lowest_mesh=lowest,
        lowest_capsules=lowest + 0.005, foot_heights=np.zeros((T, 4)), foot_contact=np.zeros((T, 4), bool),
        skating=np.full((T - 1, 4), np.nan), heatmap=np.zeros(10), summary={}, feet={},
    )  # fmt: skip
    figures = []
    original = Figure.savefig
    Figure.savefig = lambda self, *a, **k: (figures.append(self), original(self, *a, **k))[1]
    try:
        plot_report(report, tmp_path / "check.png")
    finally:
        Figure.savefig = original
    ax = figures[0].axes[0]
    assert ax.get_title() == "plausibility: 02_01.amc"
    renderer = figures[0].canvas.get_renderer()
    legend, axes = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    assert legend.x0 >= axes.x1  # entirely right of the plotting area
    assert legend.x1 <= figures[0].bbox.x1  # and still inside the picture
