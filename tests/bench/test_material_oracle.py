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
