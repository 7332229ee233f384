"""Physical plausibility: MJX checker against MuJoCo C, metrics, energies, report, CLI.

One scene (low-res default body, a box object) is built per module; every `check` call
uses batches of B frames so the MJX kernel compiles once.
"""

import jax
import jax.flatten_util
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import trimesh

from jaxmocap.body import default_body, forward
from jaxmocap.motion import save_motion
from jaxmocap.physics import (
    Ground,
    ObjectSDF,
    RigidObject,
    check,
    detect_foot_contact,
    foot_skating,
    ground_support_residual,
    make_scene,
    object_penetration,
    penetration_summary,
    pose_bones,
)
from jaxmocap.physics.metrics import FOOT_POINTS, bone_min_distance, foot_contact
from jaxmocap.rotation import matrix_to_quaternion

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
    box = RigidObject.from_trimesh("box", trimesh.creation.box(extents=BOX))
    return make_scene(body, ground=Ground(-0.85), objects=[box])


def _check(scene, poses, trans, box_pos):
    n = len(poses)
    pad = lambda x: np.concatenate([x, np.repeat(x[-1:], B - n, 0)])  # noqa: E731
    out = check(scene, pad(np.asarray(poses, float)), pad(np.asarray(trans, float)),
                object_positions=pad(np.asarray(box_pos, float)).reshape(B, 1, 3))
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
    heights = bone_min_distance(scene, out.ground, FOOT_POINTS)
    contact = foot_contact(heights)
    assert contact.all()
    joints = np.stack([np.asarray(pose_bones(scene, jnp.asarray(p), jnp.asarray(t))[1]) for p, t in zip(poses, still)])
    feet = joints[:, [scene.joint_names.index(n) for n in FOOT_POINTS]]
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


def test_ground_residual_gradients_and_descent(body):
    ground = Ground(0.0)
    rng = np.random.default_rng(2)
    pose = rng.normal(scale=0.1, size=(1, 24, 3))
    rest = np.asarray(forward(body, pose, None, np.zeros((1, 3))).vertices)
    trans = np.zeros((1, 3))
    trans[:, 1] = -rest[..., 1].min(-1) - 0.05  # 5 cm below the floor
    params = {"pose": jnp.asarray(pose), "trans": jnp.asarray(trans)}
    r = ground_support_residual(body, ground)
    flat = jax.jit(lambda p: r(p).ravel())
    jf, jr = jax.jit(jax.jacfwd(flat))(params), jax.jit(jax.jacrev(flat))(params)
    for key in params:
        assert np.isfinite(np.asarray(jf[key])).all()
        np.testing.assert_allclose(np.asarray(jf[key]), np.asarray(jr[key]), atol=1e-10)
    # Finite differences along a random direction (away from the hinge's kinks).
    v = jax.tree.map(lambda x: jnp.asarray(rng.normal(size=x.shape)), params)
    eps = 1e-6
    fd = (flat(jax.tree.map(lambda x, y: x + eps * y, params, v)) - flat(jax.tree.map(lambda x, y: x - eps * y, params, v))) / (2 * eps)
    jvp = jax.jvp(flat, (params,), (v,))[1]
    np.testing.assert_allclose(np.asarray(jvp), np.asarray(fd), atol=1e-6)

    # A few Gauss-Newton steps on ½‖r‖² push the body up out of the floor.
    @jax.jit
    def step(p):
        x, unravel = jax.flatten_util.ravel_pytree(p)
        res = lambda x: flat(unravel(x))  # noqa: E731
        Jm = jax.jacfwd(res)(x)
        dx = jnp.linalg.solve(Jm.T @ Jm + 1e-3 * jnp.eye(len(x)), Jm.T @ res(x))
        return unravel(x - dx)

    before = float(jnp.max(r(params)))
    for _ in range(5):
        params = step(params)
    assert before == pytest.approx(0.05, abs=1e-9)
    assert float(jnp.max(r(params))) < 1e-3


def test_foot_contact_detected_from_motion(body):
    from jaxmocap.motion import library

    walk = library.walk(num_frames=60, fps=30.0)
    joints = np.asarray(forward(body, walk.poses, None, walk.trans).joints)
    ids = [body.joint_index(n) for n in ("left_ankle", "right_ankle")]
    # The procedural walk's stance foot slides at 0.1-0.6 m/s (measured), hence 1 m/s here.
    ground = Ground(float(joints[:, ids, 1].min()) - 0.01)
    w = np.asarray(detect_foot_contact(joints[:, ids], ground, walk.fps, height=0.06, speed=1.0))
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
    assert (tmp_path / "out" / "walk_check.png").stat().st_size > 1000
    assert (tmp_path / "out" / "walk_contact_heatmap.ply").exists()


def test_batch_shapes(scene):
    poses = np.zeros((2, B // 2, 24, 3))
    out = check(scene, poses.reshape(B, 24, 3), np.zeros((B, 3)), object_positions=np.tile(FAR, (B, 1, 1)))
    out2 = check(scene, poses, np.zeros((2, B // 2, 3)), object_positions=np.tile(FAR, (2, B // 2, 1, 1)))
    assert out2.ground.shape == (2, B // 2, scene.geometry.num_geoms)
    np.testing.assert_allclose(np.asarray(out2.ground).reshape(B, -1), np.asarray(out.ground))
    with pytest.raises(ValueError, match="expected"):
        check(scene, np.zeros((B, 23, 3)), np.zeros((B, 3)))


def test_ground_term_plugs_into_the_solve_engine():
    """The physics residuals are engine `Term`s: LM lifts a sunk body out of the floor."""

    from jaxmocap.physics import Ground, ground_support_residual
    from jaxmocap.solve import Problem, Term, solve

    body = default_body("low")
    ground = Ground(0.0)
    rest = np.asarray(forward(body, np.zeros((24, 3))).vertices)
    soles = np.argsort(rest[:, 1])[:40]  # the lowest vertices: the soles
    pose0 = np.zeros((2, 24, 3))
    trans0 = np.tile([0.0, -rest[:, 1].min() - 0.03, 0.0], (2, 1))  # 3 cm into the floor
    data = {"pose": jnp.asarray(pose0), "trans": jnp.asarray(trans0)}
    problem = Problem([
        Term("ground", ground_support_residual(body, ground, soles), weight=1e2),
        Term("stay", lambda p, d: jnp.concatenate([(p["pose"] - d["pose"]).reshape(2, -1), p["trans"] - d["trans"]], -1), weight=1e-2),
    ])
    sol = solve(problem, {"pose": data["pose"], "trans": data["trans"]}, data, max_steps=20)
    lifted = np.asarray(forward(body, sol.value["pose"], None, sol.value["trans"]).vertices)
    assert lifted[:, soles, 1].min() > -1e-3  # was -30 mm
    assert np.isfinite(np.asarray(sol.cost)).all()
