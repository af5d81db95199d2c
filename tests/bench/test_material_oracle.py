"""bench material: the geometry-only bound (the truth's material sampled into the fitted mesh colors) and Table 1's file."""

from __future__ import annotations

import json

import numpy as np

from backend import variant

variant.choose()

from backend.bench._material_table import truth_as_mesh_colors  # noqa: E402
from backend.geometry.mesh import Mesh  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.synth.procedural import albedo_pattern, icosphere  # noqa: E402


def test_truth_sampled_into_mesh_colors_reproduces_it_on_the_same_surface():
    sphere = icosphere(3)
    albedo = albedo_pattern(sphere.vertices).astype(np.float32)
    spec = np.linspace(0.1, 0.6, sphere.n_vertices).astype(np.float32)
    rough = np.linspace(0.2, 0.8, sphere.n_vertices).astype(np.float32)
    truth = Mesh(sphere.vertices, sphere.faces, albedo, {"specular": spec, "roughness": rough})
    fitted = MeshColorMaterial(truth, 2)
    fitted.set_values("albedo", [0.5, 0.5, 0.5], "constant")
    oracle = truth_as_mesh_colors(truth, fitted, truth)
    assert np.allclose(fitted.values("albedo"), 0.5)  # the fitted material is left alone
    corners = np.zeros(truth.n_faces), np.zeros(truth.n_faces)  # each face's first corner
    got = oracle.evaluate(np.arange(truth.n_faces), *corners)
    first = truth.faces[:, 0]
    assert np.allclose(got["albedo"], albedo[first], atol=1e-4)
    assert np.allclose(got["specular"][:, 0], spec[first], atol=1e-4)
    assert np.allclose(got["roughness"][:, 0], rough[first], atol=1e-4)


def test_table_keeps_the_rows_of_meshes_not_run_again(tmp_path):
    """Rerunning one mesh of Table 1 keeps the others' rows, unless the spec changed."""
    from backend.bench._material_table import _earlier

    table = tmp_path / "table1.json"
    assert _earlier(table, {"views": 32}) == {}
    table.write_text(json.dumps({"spec": {"views": 32}, "meshes": {"dragon": {"rows": {}}}}))
    assert _earlier(table, {"views": 32}) == {"dragon": {"rows": {}}}
    assert _earlier(table, {"views": 16}) == {}
    table.write_text("{ torn")
    assert _earlier(table, {"views": 32}) == {}


def test_plain_bench_scores_a_fit_against_truth_rendered_alike(tmp_path):
    """``bench material`` end to end on a small procedural object: capture synthesised, the
    three stages fitted on the true geometry, held-out and relit views scored against the
    truth rendered here at the scoring samples, the outputs written."""
    from backend.bench.material import MaterialBench, benchmark
    from backend.capture.load import load_capture
    from backend.geometry.mesh import load_mesh, save_mesh
    from backend.synth.procedural import blob

    save_mesh(tmp_path / "blob.ply", blob(3))
    spec = MaterialBench(mesh=str(tmp_path / "blob.ply"), up="z", views=6, held_out=2, resolution=32,
                         truth_spp=32, spp=4, eval_spp=64, constant_iterations=8, diffuse_iterations=64,
                         specular_iterations=4)
    report = benchmark(spec, tmp_path / "out", lambda *args, **kwargs: None)
    m = report["metrics"]
    capture = load_capture(tmp_path / "out" / "capture")
    truth = load_mesh(capture.path(capture.ground_truth["mesh"]))
    grey = float(np.sqrt(np.mean((truth.vertex_colors - 0.5) ** 2)))  # the neutral start
    assert 0.0 < m["albedo_rmse"] < 0.7 * grey, (m, grey)
    assert m["held_out_psnr"] > 20 and m["relit_psnr"] > 18 and 0.5 < m["held_out_ssim"] <= 1
    assert [s["stage"] for s in report["stages"]] == ["constant", "diffuse", "specular"]
    for name in ("result.glb", "display.ply", "material.npz", "report.json"):
        assert (tmp_path / "out" / "run" / name).is_file()
