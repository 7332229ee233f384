"""Mesh export (trimesh round trips), batched posing, and the PNG pictures."""

import matplotlib.image
import numpy as np
import pytest
import trimesh

from conftest import assert_picture

from jaxmocap.body import forward, mannequin_body, posed_arrays, posed_vertices
from jaxmocap.motion import Motion
from jaxmocap.viz import (
    MeshExportError,
    export_mesh,
    export_sequence,
    plot_body,
    plot_pose,
    plot_sequence,
    scalars_to_colors,
)
from jaxmocap.body.mannequin import MANNEQUIN_JOINTS

T = 16  # one jit shape for the whole file (chunks of 8 or 16)


@pytest.fixture(scope="module")
def body():
    return mannequin_body(detail=0)


@pytest.fixture(scope="module")
def motion():
    rng = np.random.default_rng(1)
    t = np.arange(T) / 30.0
    poses = rng.normal(scale=0.15, size=(T, 24, 3))
    poses[:, 0] = [0.0, 0.4, 0.0]  # a fixed yaw
    trans = np.stack([0.3 * t, 0.02 * np.sin(6 * t), 1.2 * t], 1)
    return Motion(poses=poses, trans=trans, fps=30.0, name="random")


@pytest.fixture(scope="module")
def posed(body, motion):
    return posed_vertices(body, motion, chunk=8)


def test_mannequin_layout(body):
    assert body.num_joints == 24 and body.num_vertices == 656
    joints = np.asarray(body.J_regressor @ body.v_template)
    np.testing.assert_allclose(joints, MANNEQUIN_JOINTS, atol=1e-5)
    np.testing.assert_allclose(np.asarray(body.weights).sum(1), 1.0)


def test_posed_vertices_matches_forward(body, motion, posed):
    vertices, joints = posed
    assert vertices.shape == (T, body.num_vertices, 3) and joints.shape == (T, 24, 3)
    out = forward(
        body, np.asarray(motion.poses[[0, 13]], np.float32), None, np.asarray(motion.trans[[0, 13]], np.float32)
    )
    np.testing.assert_allclose(vertices[[0, 13]], out.vertices, atol=1e-5)
    np.testing.assert_allclose(joints[[0, 13]], out.joints, atol=1e-5)
    v5, j5 = posed_vertices(body, motion, frames=slice(3, 8))  # padded to the same 8-frame chunk
    np.testing.assert_allclose(v5, vertices[3:8], atol=1e-6)


def test_posed_arrays_per_frame_betas(body, motion, posed):
    # Per-frame betas (a fit's first stage) pose each frame with its own shape.
    betas = np.random.default_rng(2).normal(size=(T, 10))
    vertices, joints = posed_arrays(body, motion.poses, betas, motion.trans, chunk=8, dtype=np.float64)
    assert vertices.dtype == np.float64 and vertices.shape == (T, body.num_vertices, 3)
    out = forward(body, np.asarray(motion.poses[[2, 11]], np.float32), betas[[2, 11]].astype(np.float32),
                  np.asarray(motion.trans[[2, 11]], np.float32))  # fmt: skip
    np.testing.assert_allclose(vertices[[2, 11]], out.vertices, atol=1e-5)
    np.testing.assert_allclose(joints[[2, 11]], out.joints, atol=1e-5)
    shared, _ = posed_arrays(body, motion.poses, betas[4], motion.trans, chunk=8)
    np.testing.assert_allclose(shared[4], vertices[4], atol=1e-5)
    np.testing.assert_array_equal(posed_arrays(body, motion.poses, None, motion.trans, chunk=8)[0], posed[0])
    with pytest.raises(ValueError, match=r"betas has shape \(3, 10\); expected \(B,\) for every frame or \(16, B\)"):
        posed_arrays(body, motion.poses, betas[:3], motion.trans)
    with pytest.raises(ValueError, match=r"trans contains NaN or inf \(first at index \(5, 1\)\)"):
        posed_arrays(body, motion.poses, None, np.where(np.arange(T)[:, None] == 5, [0.0, np.nan, 0.0], motion.trans))


@pytest.mark.parametrize("suffix", ["ply", "obj", "glb"])
def test_export_mesh_round_trip(tmp_path, body, posed, suffix):
    vertices = posed[0][5]
    path = export_mesh(vertices, body.faces, tmp_path / "sub" / f"pose.{suffix}")
    assert path.is_file()
    mesh = trimesh.load(path, process=False, force="mesh")
    assert mesh.vertices.shape == vertices.shape
    np.testing.assert_allclose(mesh.vertices, vertices, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, body.faces)


def test_export_mesh_colors(tmp_path, body, posed):
    values = np.linspace(0.0, 1.0, body.num_vertices)
    path = export_mesh(posed[0][0], body.faces, tmp_path / "heat.ply", colors=values, cmap="inferno")
    mesh = trimesh.load(path, process=False)
    expected = scalars_to_colors(values, "inferno")
    np.testing.assert_array_equal(mesh.visual.vertex_colors, expected)
    assert expected.shape == (body.num_vertices, 4) and expected.dtype == np.uint8


def test_export_mesh_errors(tmp_path, body, posed):
    with pytest.raises(MeshExportError, match=r"\.stl"):
        export_mesh(posed[0][0], body.faces, tmp_path / "pose.stl")
    with pytest.raises(MeshExportError, match="colors"):
        export_mesh(posed[0][0], body.faces, tmp_path / "pose.ply", colors=np.zeros(3))
    with pytest.raises(MeshExportError, match=r"\(V, 3\)"):
        export_mesh(posed[0], body.faces, tmp_path / "pose.ply")


def test_export_sequence(tmp_path, body, posed):
    vertices = posed[0]
    paths = export_sequence(vertices, body.faces, tmp_path / "ply", every=3)
    assert [p.name for p in paths] == [f"frame_{t:04d}.ply" for t in range(0, T, 3)]
    assert sorted(p.name for p in (tmp_path / "ply").iterdir()) == [p.name for p in paths]
    last = trimesh.load(paths[-1], process=False)
    np.testing.assert_allclose(last.vertices, vertices[15], atol=1e-6)

    heat = np.random.default_rng(0).random((T, body.num_vertices))
    (glb,) = export_sequence(vertices, body.faces, tmp_path / "glb", fmt="glb", every=5, colors=heat)
    scene = trimesh.load(glb, process=False)
    names = sorted(scene.graph.nodes_geometry)
    assert names == ["frame_0000", "frame_0005", "frame_0010", "frame_0015"]
    assert len(scene.geometry) == 4
    mesh = scene.geometry[scene.graph[names[2]][1]]  # (transform, geometry name) of a node
    np.testing.assert_allclose(mesh.vertices, vertices[10], atol=1e-6)

    with pytest.raises(MeshExportError, match="stl"):
        export_sequence(vertices, body.faces, tmp_path / "x", fmt="stl")


def test_plot_pose(tmp_path, body, posed):
    path = plot_pose(posed[1][4], body.parents, view="side", title="frame 4", path=tmp_path / "pose.png")
    assert_picture(path, min_bytes=5_000)


def test_plot_body(tmp_path, body, posed):
    vertices, joints = posed
    path = plot_body(vertices[7], body.faces, tmp_path / "pics" / "body.png", joints=joints[7])
    assert_picture(path)
    heat = vertices[7][:, 1]  # height as a stand-in for contact heat
    path = plot_body(vertices[7], body.faces, tmp_path / "heat.png", vertex_values=heat, views=("front",))
    assert_picture(path)


def test_plot_sequence(tmp_path, body, posed):
    path = plot_sequence(posed[1], body.parents, tmp_path / "strip.png", num_panels=6, fps=30.0)
    assert_picture(path, min_bytes=30_000)
    image = matplotlib.image.imread(path)
    assert image.shape[1] > image.shape[0]  # a wide filmstrip page
    with pytest.raises(ValueError, match="expected"):
        plot_sequence(posed[1][:, :5], body.parents, tmp_path / "bad.png")
