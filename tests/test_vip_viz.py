"""VIP pictures (issue 16): overlay PNGs, error curves and the GLB/PLY scene, from plain arrays."""

import matplotlib.image
import numpy as np
import pytest
import trimesh

from conftest import assert_picture

from jaxmocap.viz.vip import error_over_time_png, overlay_png, scene_glb

W, H = 320, 240
# A COCO-18 stick person (pixels, standing, facing the camera), its left side on image right.
PERSON = np.array([
    [0, -60], [0, -45], [-15, -45], [-22, -25], [-25, -5], [15, -45], [22, -25], [25, -5], [-9, 0],
    [-10, 25], [-10, 50], [9, 0], [10, 25], [10, 50], [-4, -64], [4, -64], [-8, -62], [8, -62],
], float)  # fmt: skip


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=1, radius=0.3)  # 42 vertices, 80 faces


def _scene_arrays():
    rng = np.random.default_rng(0)
    model = np.stack([PERSON + [100, 140], PERSON + [220, 130]])  # (P=2, 18, 2)
    det = np.concatenate([model + rng.normal(scale=2.0, size=model.shape), np.ones((2, 18, 1))], -1)
    det[1, 9:11, 2] = 0.0  # a missed right leg
    stray = np.concatenate([PERSON[None] * 0.6 + [280, 60], np.full((1, 18, 1), 0.5)], -1)
    return np.concatenate([det, stray]), np.array([0, 1, -1]), model


def test_overlay_png(tmp_path, sphere):
    det, assignment, model = _scene_arrays()
    # A projected "mesh" per person: the sphere's vertices scaled into each person's box.
    verts = np.stack([sphere.vertices[:, :2] * [60, 200] + m.mean(0) for m in model])
    path = overlay_png(tmp_path / "overlay.png", (W, H), det, assignment, model, verts, sphere.faces, title="frame 0")
    assert_picture(path, min_bytes=5_000, min_colour_fraction=0.02)
    image = matplotlib.image.imread(path)
    assert image.shape[1] > image.shape[0]  # landscape like the image
    background = np.linspace(0, 1, H * W * 3).reshape(H, W, 3)
    assert_picture(overlay_png(tmp_path / "points.png", (W, H), det, assignment, model, verts, background=background))
    with pytest.raises(ValueError, match="assignment"):
        overlay_png(tmp_path / "bad.png", (W, H), det, [0, 2, -1], model)
    with pytest.raises(ValueError, match="projected_joints"):
        overlay_png(tmp_path / "bad.png", (W, H), det, assignment, model[..., :1])


def test_error_over_time_png(tmp_path):
    t = np.arange(90) / 30.0
    vip = 40 + 5 * np.sin(t)
    vip[30:40] = np.nan  # frames without a value are gaps
    path = error_over_time_png(tmp_path / "err.png", {"VIP": vip, "IT": 70 + 10 * np.cos(t)}, 30.0, "MPJPE [mm]")
    assert_picture(path, min_bytes=5_000, min_colour_fraction=0.005)
    with pytest.raises(ValueError, match=r"\(T,\)"):
        error_over_time_png(tmp_path / "bad.png", {"VIP": np.zeros((3, 2))}, 30.0)


def _camera(T):
    centres = np.stack([np.linspace(-1, 1, T), np.full(T, 1.5), np.full(T, 4.0)], -1)
    R = np.tile(np.diag([1.0, -1.0, -1.0]), (T, 1, 1))  # looking along -z, image down = world down
    return centres, R


def test_scene_glb(tmp_path, sphere):
    P, T = 2, 8
    V = len(sphere.vertices)
    verts = sphere.vertices[None, None] + np.stack([[0.1 * t, 1.0, 0.0] for t in range(T)])[None, :, None]
    verts = np.concatenate([verts, verts + [1.0, 0.0, 0.0]])  # (P, T, V, 3)
    centres, R = _camera(T)
    path = scene_glb(tmp_path / "scene.glb", verts, sphere.faces, centres, R)
    scene = trimesh.load(path)
    meshes = {k: g for k, g in scene.geometry.items() if isinstance(g, trimesh.Trimesh)}
    assert len(meshes) == P * 5 + 5  # 5 frames by default: bodies and camera pyramids
    assert sum(len(m.vertices) for k, m in meshes.items() if k.startswith("person")) == P * 5 * V
    np.testing.assert_allclose(meshes["person1_frame0007"].vertices, verts[1, 7], atol=1e-6)
    pyramid = meshes["camera_0000"].vertices
    np.testing.assert_allclose(pyramid[0], centres[0], atol=1e-6)
    assert (pyramid[1:, 2] < centres[0, 2]).all()  # in front of the camera: towards -z
    assert isinstance(scene.geometry["camera_path"], trimesh.path.Path3D)

    one = trimesh.load(scene_glb(tmp_path / "one.glb", verts[:, 0], sphere.faces, centres, R, frames=[0, 7]))
    assert sorted(one.geometry) == [
        "camera_0000",
        "camera_0007",
        "camera_path",
        "person0_frame0000",
        "person1_frame0000",
    ]
    ply = trimesh.load(scene_glb(tmp_path / "scene.ply", verts, sphere.faces, centres, R, frames=[3]))
    assert len(ply.vertices) == P * V + 5
    with pytest.raises(ValueError, match="vertices"):
        scene_glb(tmp_path / "bad.glb", verts[:, :3], sphere.faces, centres, R)
    with pytest.raises(ValueError, match="frames"):
        scene_glb(tmp_path / "bad.glb", verts, sphere.faces, centres, R, frames=[8])
