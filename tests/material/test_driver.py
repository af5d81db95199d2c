"""The driver the reconstruction loop calls: masks checked, labels voted, schedule cycles."""

import numpy as np
import pytest
from PIL import Image

from backend import variant

variant.choose()

from backend.capture.images import write_image, write_mask  # noqa: E402
from backend.capture.model import Capture, Frame  # noqa: E402
from backend.errors import InputError  # noqa: E402
from backend.material.driver import MaterialDriver  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.material.schedule import MaterialSchedule  # noqa: E402
from backend.material.stages import FitSettings  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402
from tests.material.test_labels import pixel_labels  # noqa: E402

RES = 32


def two_material_capture(root):
    mesh = procedural.blob(3)
    top = (mesh.vertices[mesh.faces].mean(1)[:, 2] > 0.05).astype(int)
    truth = MeshColorMaterial(mesh, 1, top, 2)
    truth.set_values("albedo", [[0.7, 0.3, 0.1], [0.1, 0.4, 0.7]])
    truth.set_values("specular", 0.2)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(6), np.zeros(3), 0.6, RES)
    lights = [layout.paper_lights(c, 2.0) for c in cams]
    ref = SceneRenderer(mesh, truth.field, cams, lights, None, RenderSettings(spp=32), rgba=True)
    frames, images = [], []
    for i, cam in enumerate(cams):
        rgba = ref.render_numpy(i, seed=i)
        images.append(rgba[..., :3])
        image, mask, mat = root / f"images/{i}.exr", root / f"masks/{i}.png", root / f"materials/{i}.png"
        write_image(image, rgba[..., :3])
        write_mask(mask, rgba[..., 3])
        mat.parent.mkdir(exist_ok=True)
        labels = pixel_labels(mesh, top + 1, cam)
        labels[(labels == 0) & (rgba[..., 3] >= 0.5)] = 1  # anti-aliased rim pixels: any label
        Image.fromarray(labels.astype(np.uint8)).save(mat)
        frames.append(Frame(str(i), image, cam, mask=mask, material_mask=mat, lights=lights[i]))
    return mesh, top, Capture(root, frames), images


def test_driver_labels_and_cycles(tmp_path):
    mesh, top, capture, images = two_material_capture(tmp_path)
    cams = [f.camera for f in capture.frames]
    masks = [np.asarray(Image.open(f.mask), np.float32) / 255 for f in capture.frames]
    driver = MaterialDriver(capture, resolution=1, settings=FitSettings(iterations=20),
                            schedule=MaterialSchedule(constant_cycles=1))
    material = driver.material(mesh, cams, images, masks)
    assert material.n_materials == 2 and np.mean(material.labels == top) > 0.97
    renderer = SceneRenderer(mesh, material.field, cams, [f.lights for f in capture.frames], None,
                             RenderSettings(spp=4, max_depth=2, integrator="prb"))
    driver.cycle(renderer, images, masks, material)
    albedo = material.values("albedo")
    assert albedo[1, 2] > albedo[1, 0] and albedo[0, 0] > albedo[0, 2]  # blue top, orange bottom
    assert driver.schedule.stage == "diffuse" and not driver.done
    material.on_remesh(procedural.blob(2), old_mesh=mesh, reset=False)
    driver.on_remesh(procedural.blob(2), material, cams, reset=False)  # resampled: the stage goes on
    assert driver.schedule.stage == "diffuse"
    material.on_remesh(procedural.blob(2), old_mesh=procedural.blob(2))
    driver.on_remesh(procedural.blob(2), material, cams)  # restarted from grey: constants first
    assert driver.schedule.stage == "constant" and material.n_faces == procedural.blob(2).n_faces
    report = driver.report()
    assert report["labels"]["materials"] == [1, 2] and report["stages"][0]["stage"] == "constant"
    driver.finalise()
    driver.finalise()  # once only
    assert driver.settings.iterations == 80 and driver.schedule.final and driver.schedule.patience == 2


def test_settle_keeps_a_specular_texture_only_with_views_left_out(tmp_path):
    mesh, top, capture, images = two_material_capture(tmp_path)
    cams = [f.camera for f in capture.frames]
    masks = [np.asarray(Image.open(f.mask), np.float32) / 255 for f in capture.frames]
    for every, checked in ((8, False), (2, True)):  # 6 views: none left out at 8, three at 2
        driver = MaterialDriver(capture, resolution=1, settings=FitSettings(check_every=every))
        material = driver.material(mesh, cams, images, masks)
        renderer = SceneRenderer(mesh, material.field, cams, [f.lights for f in capture.frames], None,
                                 RenderSettings(spp=8, max_depth=2, integrator="prb"))
        assert driver.settle(renderer, images, masks, material) is None  # constant specular: nothing to test
        material.make_spatial("specular")
        rng = np.random.default_rng(1)
        material.set_values("specular", np.clip(0.2 + rng.normal(0, 0.2, material.layout.n_samples), 0.01, 0.99))
        check = driver.settle(renderer, images, masks, material)
        assert (check is not None) == checked and driver.report()["specular_check"] == check
        if checked:  # the truth's lobe is uniform (0.2): its noisy texture gives way to its mean
            assert check["views"] == [1, 3, 5] and check["kept"] == "constant" and check["constant"] < check["colors"]
            assert material.channels["specular"].kind == "constant"
        else:
            assert material.channels["specular"].kind == "colors"


def test_driver_refuses_bad_masks_before_any_work(tmp_path):
    mesh, top, capture, images = two_material_capture(tmp_path)
    capture.frames[3].material_mask = None
    with pytest.raises(InputError, match="frame 3 has no material_mask"):
        MaterialDriver(capture)
