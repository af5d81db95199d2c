"""Material reconstruction: diffuse albedo, specular reflectance and roughness on the mesh,
each one constant per material or *mesh colors* (Yuksel et al. 2010), so no UV map is needed
while the mesh keeps changing.

- ``meshcolors``: the shared-sample layout (vertex and edge samples shared, interior samples
  per face; ``table`` maps the paper's per-triangle index t K + k into it), numpy lookup.
- ``field``: the Dr.Jit lookup (``MeshColorsField.lookup(si, active)``) with sigmoid
  reparameterised latents, exact gradients through ``dr.gather``.
- ``model``: ``MeshColorMaterial``, the object the reconstruction loop swaps in: ``field``,
  ``parameters()``, ``on_subdivide``, ``on_remesh``, ``display``, ``save``/``load``.
- ``labels``: material masks checked before any work, clustering, per-face majority vote.
- ``stages``: the optimisation stages (constants, textured diffuse with highlight masking and
  the environment brightness factor, textured specular) and ``MaterialSchedule``.
- ``export``: baked texture atlas and ``write_glb`` (glTF 2.0 with KHR_materials_specular).

Typical use by the loop::

    labels_in = labels.load_material_labels(capture)           # at start: bad masks -> InputError
    material = MeshColorMaterial(mesh, resolution=4)
    renderer = SceneRenderer(mesh, material.field, cams, lights, env, RenderSettings(integrator="prb"))
    found = labels.face_labels(mesh, cams, labels_in, images, masks, n_materials)
    material.set_labels(found.labels, found.n_materials)      # found.disagreement: for the report
    schedule = stages.MaterialSchedule()
    while schedule.stage != "done":                             # alternate with geometry cycles
        ...geometry...; material.on_subdivide(old, new) / material.on_remesh(new); schedule.on_remesh()
        stages.run_cycle(schedule, renderer, images, masks, material)
    export.write_glb(run / "result.glb", mesh, material)
"""
