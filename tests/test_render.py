"""Pictures: the mesh and point renderers, side_by_side, the PNG helpers."""

import numpy as np
import pytest
import trimesh

from geosynth.io.pictures import (View, render_mesh, render_mesh_png, render_points, render_points_png, side_by_side,
                             text_image)

SIZE = (96, 72)
WHITE = np.array([255, 255, 255])


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=3)


def object_mask(image, background=WHITE):
    return (np.abs(image.astype(int) - background) > 3).any(-1)


def test_mesh_picture_shows_the_object(sphere):
    img = render_mesh(sphere, size=SIZE)
    assert img.shape == (72, 96, 3) and img.dtype == np.uint8
    mask = object_mask(img)
    assert mask[30:42, 40:56].all()  # the middle is the object
    assert not mask[:3].any() and not mask[:, :3].any()  # a margin of background
    assert 0.25 < mask.mean() < 0.8


def test_shading_varies_with_the_normal(sphere):
    img = render_mesh(sphere, size=SIZE, specular=0.0).astype(float)
    lum = img.mean(-1)[object_mask(img.astype(np.uint8))]
    assert lum.max() - lum.min() > 80  # lit side and far side differ
    # the light comes from the upper left: that quarter of the ball is brighter
    upper_left, lower_right = img[20:32, 30:44].mean(), img[44:56, 54:68].mean()
    assert upper_left > lower_right + 20
    # a flat face facing the light is uniform
    box = trimesh.creation.box(extents=(1, 1, 1))
    flat = render_mesh(box, size=SIZE, smooth=False, supersample=1)
    assert len(np.unique(flat.reshape(-1, 3), axis=0)) <= 4  # three visible faces + background


def test_deterministic(sphere):
    a = render_mesh(sphere, size=SIZE)
    b = render_mesh(sphere.copy(), size=SIZE)
    np.testing.assert_array_equal(a, b)


def test_occlusion_nearest_wins():
    red = trimesh.creation.box(extents=(1, 1, 1))
    blue = trimesh.creation.box(extents=(1, 1, 1)).apply_translation([-5, 5, 0])
    both = trimesh.util.concatenate([red, blue])
    colours = np.zeros((len(both.faces), 3))
    colours[:12] = (255, 0, 0)
    colours[12:] = (0, 0, 255)
    # the camera stands toward (-x, +y) from the centre: the blue box is in front of the red one
    img = render_mesh(both, size=SIZE, face_colors=colours, view=View(azimuth=135.0, elevation=0.0, fov=20))
    centre = img[30:42, 42:54].astype(int)
    assert (centre[..., 2] > centre[..., 0]).all()
    img = render_mesh(both, size=SIZE, face_colors=colours, view=View(azimuth=-45.0, elevation=0.0, fov=20))
    centre = img[30:42, 42:54].astype(int)
    assert (centre[..., 0] > centre[..., 2]).all()


def test_colours_and_views(sphere):
    vc = np.zeros((len(sphere.vertices), 3))
    vc[:, 0] = 255 * (sphere.vertices[:, 2] > 0)
    img = render_mesh(sphere, size=SIZE, vertex_colors=vc, view=(0.0, 0.0))
    assert img[20, 48, 0] > img[20, 48, 2] and img[52, 48, 0] < img[20, 48, 0]  # red top, dark bottom
    ortho = render_mesh(sphere, size=SIZE, view=View(fov=0))
    assert object_mask(ortho)[36, 48]
    assert render_mesh((sphere.vertices, sphere.faces), size=SIZE).shape == (72, 96, 3)


def test_open_surface_back_faces():
    disk = trimesh.creation.annulus(0.0001, 1.0, 0.01)
    top = trimesh.Trimesh(disk.vertices, disk.faces[disk.face_normals[:, 2] > 0.9], process=False)
    from_above = render_mesh(top, size=SIZE, view=(0.0, 60.0), back_color=(255, 0, 0))
    from_below = render_mesh(top, size=SIZE, view=(0.0, -60.0), back_color=(255, 0, 0))
    assert from_below[36, 48, 0] > from_below[36, 48, 2] + 50  # the back side in back_color
    assert not from_above[36, 48, 0] > from_above[36, 48, 2] + 50


def test_many_faces_render_fast(sphere):
    import time

    big = trimesh.creation.icosphere(subdivisions=7)  # 327,680 faces
    t = time.perf_counter()
    img = render_mesh(big, size=(320, 240))
    assert time.perf_counter() - t < 15
    assert object_mask(img)[120, 160]


def test_points_picture():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(4000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    img = render_points(p, normals=p, size=SIZE)
    mask = object_mask(img)
    assert mask[30:42, 40:56].all()
    lum = img.mean(-1)[mask]
    assert lum.max() - lum.min() > 60
    np.testing.assert_array_equal(img, render_points(p, normals=p, size=SIZE))
    plain = render_points(p, colors=np.tile([0, 200, 0], (4000, 1)), shading=False, size=SIZE)
    assert (plain[36, 48] == [0, 200, 0]).all()
    assert object_mask(render_points(p, size=SIZE))[36, 48]  # no normals: sphere splats


def test_side_by_side_and_labels():
    a = np.zeros((20, 30, 3), np.uint8)
    b = np.full((10, 12), 128, np.uint8)
    row = side_by_side([a, b], gap=4)
    assert row.shape == (20, 46, 3)
    assert (row[5:15, 34:46] == 128).all() and (row[:5, 34:] == 255).all()
    labelled = side_by_side([a, b], labels=["A1", "x"], gap=4, scale=1)
    text_height = text_image("x", scale=1).shape[0]
    assert labelled.shape[0] == 20 + text_height + 8
    assert (labelled[4:4 + text_height, :30] < 128).any()  # text drawn above each picture
    assert (labelled[4:4 + text_height, 34:] < 128).any()
    assert (labelled[:4] == 255).all() and (labelled[4 + text_height:8 + text_height] == 255).all()
    t = text_image("Hi 1", scale=2)
    assert t.shape[0] == text_image("x", scale=2).shape[0] > text_height  # the height follows the scale only
    assert t.shape[1] > text_image("H", scale=2).shape[1] and t.dtype == np.uint8
    assert t.min() < 80 and t.max() == 255  # dark letters on the white background
    assert not np.array_equal(text_image("hi"), text_image("HI"))  # lower case is drawn as such
    with pytest.raises(ValueError, match="scale"):
        text_image("x", scale=0)


def test_png_helpers(tmp_path, sphere):
    out = render_mesh_png(sphere, tmp_path / "a.png", size=SIZE)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = render_points_png(sphere.vertices, tmp_path / "b.png", normals=sphere.vertex_normals, size=SIZE)
    assert out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.png"]


def test_invalid_input(sphere):
    with pytest.raises(TypeError, match="Trimesh"):
        render_mesh("sphere.ply")
    with pytest.raises(ValueError, match="faces"):
        render_mesh(trimesh.Trimesh(sphere.vertices, np.zeros((0, 3), int)))
    bad = sphere.vertices.copy()
    bad[0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        render_mesh((bad, sphere.faces))
    with pytest.raises(ValueError, match="out of range"):
        render_mesh((sphere.vertices, sphere.faces + len(sphere.vertices)))
    with pytest.raises(ValueError, match="size"):
        render_mesh(sphere, size=(0, 10))
    with pytest.raises(ValueError, match="size"):
        render_mesh(sphere, size=(64,))
    with pytest.raises(ValueError, match="face_colors"):
        render_mesh(sphere, face_colors=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="not both"):
        render_mesh(sphere, face_colors=np.zeros((len(sphere.faces), 3)),
                    vertex_colors=np.zeros((len(sphere.vertices), 3)))
    with pytest.raises(ValueError, match="color"):
        render_mesh(sphere, color=(300, 0, 0))
    with pytest.raises(ValueError, match="elevation"):
        render_mesh(sphere, view=View(elevation=100))
    with pytest.raises(TypeError, match="view"):
        render_mesh(sphere, view="top")
    with pytest.raises(ValueError, match="supersample"):
        render_mesh(sphere, supersample=8)
    with pytest.raises(ValueError, match="points"):
        render_points(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="NaN"):
        render_points(np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="normals"):
        render_points(np.zeros((3, 3)), normals=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="radius"):
        render_points(np.eye(3), radius=0)
    with pytest.raises(ValueError, match="at least one"):
        side_by_side([])
    with pytest.raises(ValueError, match="labels"):
        side_by_side([np.zeros((4, 4, 3), np.uint8)], labels=["a", "b"])
    with pytest.raises(ValueError, match="uint8"):
        side_by_side([np.zeros((4, 4, 3))])
