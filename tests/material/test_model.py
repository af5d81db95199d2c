"""The material model: display mesh on the samples, constants <-> mesh colors, re-mesh, persistence."""

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.geometry.mesh import load_mesh, save_mesh  # noqa: E402
from backend.material.model import NEUTRAL, MeshColorMaterial  # noqa: E402
from backend.material.meshcolors import MeshColorLayout  # noqa: E402
from tests.material.helpers import lookup_numpy, lumpy, random_points  # noqa: E402
from tests.material.test_meshcolors import textured  # noqa: E402


@pytest.mark.parametrize("r", [0, 1, 2, 4])
def test_display_mesh_sits_on_the_samples(r, tmp_path):
    mesh = lumpy(1)
    m = textured(mesh, r)
    d = m.display(mesh)
    if r == 0:
        assert d.n_faces == mesh.n_faces and d.n_vertices == 3 * mesh.n_faces
        assert np.allclose(d.vertex_colors[d.faces[:, 0]], m.values("albedo"), atol=1e-6)
    else:
        assert d.n_faces == mesh.n_faces * r * r
        assert d.n_vertices == m.layout.n_samples  # one vertex per shared sample: watertight
        pos = m.layout.sample_positions(mesh.vertices)
        order = np.lexsort(pos.T)
        order_d = np.lexsort(d.vertices.T)
        assert np.allclose(pos[order], d.vertices[order_d])
        assert np.allclose(m.values("albedo")[order], d.vertex_colors[order_d], atol=1e-6)
        assert np.allclose(m.values("roughness")[order, 0], d.attributes["roughness"][order_d], atol=1e-6)
        # the display triangles are the sub-triangles, with the faces' orientation
        n_face = np.repeat(mesh.face_normals(), r * r, 0)
        assert np.all((d.face_normals() * n_face).sum(1) > 0.999)
    save_mesh(tmp_path / "snap.ply", d)
    back = load_mesh(tmp_path / "snap.ply")
    assert np.allclose(back.vertex_colors, d.vertex_colors)
    assert set(back.attributes) == {"specular", "roughness", "nx", "ny", "nz"}
    np.testing.assert_array_equal(back.shading_normals, d.shading_normals)


def test_display_splits_vertices_at_material_boundaries():
    mesh = lumpy(1)
    labels = (mesh.vertices[mesh.faces].mean(1)[:, 2] > 0).astype(int)
    m = MeshColorMaterial(mesh, 2, labels, 2)
    m.set_values("albedo", [[0.9, 0.1, 0.1], [0.1, 0.1, 0.9]])
    d = m.display(mesh)
    assert d.n_vertices > mesh.n_vertices  # boundary vertices duplicated per material
    red = d.vertex_colors[:, 0] > 0.5
    assert red.sum() > 0 and (~red).sum() > 0
    # every display face is single-coloured
    assert np.all(red[d.faces].all(1) | (~red[d.faces]).all(1))


def test_constant_to_mesh_colors_keeps_the_look():
    mesh = lumpy(1)
    labels = (mesh.vertices[mesh.faces].mean(1)[:, 0] > 0).astype(int)
    m = MeshColorMaterial(mesh, 3, labels, 2)
    m.set_values("specular", [[0.3], [0.05]])
    rng = np.random.default_rng(0)
    face, b = random_points(mesh.n_faces, 2000, rng)
    before = lookup_numpy(m, face, b[:, 1], b[:, 2])
    m.make_spatial("specular")
    after = lookup_numpy(m, face, b[:, 1], b[:, 2])
    # interior points of faces away from the material boundary keep their value exactly
    boundary = np.zeros(mesh.n_faces, bool)
    verts_of = [set(np.flatnonzero(labels == k)) for k in (0, 1)]
    v0 = np.unique(mesh.faces[list(verts_of[0])])
    v1 = np.unique(mesh.faces[list(verts_of[1])])
    shared = np.intersect1d(v0, v1)
    boundary[np.isin(mesh.faces, shared).any(1)] = True
    far = ~boundary[face]
    assert far.sum() > 100
    assert np.abs(after["specular"][far] - before["specular"][far]).max() < 1e-5
    m.make_constant("specular")
    assert np.allclose(m.values("specular")[:, 0], [0.3, 0.05], atol=0.03)


def test_remesh_carries_labels_and_restarts_from_grey():
    mesh = lumpy(2)
    labels = (mesh.vertices[mesh.faces].mean(1)[:, 2] > 0).astype(int)
    m = textured(mesh, 2)
    m.set_labels(labels, 2)
    coarse = lumpy(1)
    m.on_remesh(coarse)
    assert m.n_faces == coarse.n_faces
    expect = (coarse.vertices[coarse.faces].mean(1)[:, 2] > 0).astype(int)
    assert np.mean(m.labels == expect) > 0.95
    assert all(ch.kind == "constant" for ch in m.channels.values())
    assert np.allclose(m.values("albedo"), NEUTRAL["albedo"], atol=1e-5)
    # resampling instead of the reset keeps the texture approximately
    m2 = textured(mesh, 2, seed=3)
    values = m2.evaluate(np.arange(mesh.n_faces), np.full(mesh.n_faces, 1 / 3), np.full(mesh.n_faces, 1 / 3))
    m2.on_remesh(mesh.copy(), reset=False)
    again = m2.evaluate(np.arange(mesh.n_faces), np.full(mesh.n_faces, 1 / 3), np.full(mesh.n_faces, 1 / 3))
    assert np.abs(again["albedo"] - values["albedo"]).max() < 1e-5


def test_set_resolution_refining_is_exact():
    mesh = lumpy(1)
    m = textured(mesh, 2)
    rng = np.random.default_rng(1)
    face, b = random_points(mesh.n_faces, 3000, rng)
    before = lookup_numpy(m, face, b[:, 1], b[:, 2])
    m.set_resolution(4)
    assert isinstance(m.layout, MeshColorLayout) and m.resolution == 4
    after = lookup_numpy(m, face, b[:, 1], b[:, 2])
    assert np.abs(after["albedo"] - before["albedo"]).max() < 1e-5


def test_save_and_load_round_trip(tmp_path):
    mesh = lumpy(1)
    m = textured(mesh, 3)
    m.set_labels((np.arange(mesh.n_faces) % 3), 3)
    m.make_constant("roughness")
    m.set_values("roughness", [[0.2], [0.5], [0.8]])
    m.light_factor = 1.3
    m.save(tmp_path / "material.npz")
    back = MeshColorMaterial.load(tmp_path / "material.npz")
    assert back.light_factor == pytest.approx(1.3) and back.n_materials == 3
    for name in m.CHANNELS:
        assert back.channels[name].kind == m.channels[name].kind
        assert np.allclose(back.values(name), m.values(name), atol=1e-6)
    assert m.summary()["roughness"] == [[0.2], [0.5], [0.8]]


def test_loop_interface_accepts_numpy_latents():
    """The loop keeps best latents as numpy arrays and loads them back (backtracking)."""
    mesh = lumpy(1)
    m = textured(mesh, 2)
    assert set(m.trainable) == set(m.CHANNELS)
    saved = {n: np.array(z, np.float64) for n, z in m.parameters().items()}
    before = m.values("albedo")
    objects = {n: z for n, z in m.parameters().items()}
    m.load_parameters({n: z + 1.0 for n, z in saved.items()})
    assert not np.allclose(m.values("albedo"), before)
    m.load_parameters(saved)
    assert np.allclose(m.values("albedo"), before, atol=1e-6)
    assert all(m.parameters()[n] is objects[n] for n in objects)  # updated in place
    with pytest.raises(ValueError):
        m.load_parameters({"albedo": saved["albedo"][:-3]})


def test_display_mesh_shades_like_the_fitted_surface():
    """The display mesh's split faces are flat; its Phong normals make it render like the
    smooth mesh it was made from (same mesh colors), which its facet normals do not."""
    from backend.metrics.image import psnr
    from backend.render.scene import RenderSettings, SceneRenderer
    from backend.render.views import display_field
    from backend.synth import layout

    mesh = lumpy(1)  # coarse, so facets are large
    m = MeshColorMaterial(mesh, 4)
    m.make_spatial("albedo")  # mesh colors: the display mesh splits every face 4 x 4
    m.set_values("albedo", [0.6, 0.5, 0.4])
    m.set_values("specular", 0.3)
    m.set_values("roughness", 0.35)
    d = m.display(mesh)
    assert d.n_faces == 16 * mesh.n_faces
    corners = [np.flatnonzero(np.all(np.isclose(d.vertices, v), axis=1))[0] for v in mesh.vertices]
    np.testing.assert_allclose(d.shading_normals[corners], mesh.vertex_normals(), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(d.shading_normals, axis=1), 1.0, atol=1e-6)
    faceted = d.copy()
    for k in ("nx", "ny", "nz"):
        del faceted.attributes[k]
    cams = layout.orbit_cameras(layout.fibonacci_sphere(2), np.zeros(3), 1.2, 48)
    lights = [layout.paper_lights(c, 3.0) for c in cams]
    settings = RenderSettings(spp=64, max_depth=2, integrator="path")

    def images(m_, field):
        renderer = SceneRenderer(m_, field, cams, lights, None, settings)
        return np.concatenate([renderer.render_numpy(i, seed=3)[..., :3] for i in range(len(cams))])

    smooth = images(mesh, m.field)
    phong, flat = (psnr(images(x, display_field(x)), smooth) for x in (d, faceted))
    print(f"display vs smooth mesh: Phong normals {phong:.1f} dB, facet normals {flat:.1f} dB")
    assert phong > 35 and phong > flat + 6, (phong, flat)
