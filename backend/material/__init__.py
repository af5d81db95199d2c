"""Material reconstruction: diffuse albedo, specular reflectance and roughness on the mesh,
each one constant per material or *mesh colors* (Yuksel et al. 2010), so no UV map is needed
while the mesh keeps changing.

- ``meshcolors``: the shared-sample layout (vertex and edge samples shared, interior samples
  per face; ``table`` maps the paper's per-triangle index t K + k into it), numpy lookup.
- ``field``: the Dr.Jit lookup (``MeshColorsField.lookup(si, active)``) with sigmoid
  reparameterised latents, exact gradients through ``dr.gather``.
- ``base``: ``Material``, the interface every material model offers the loop.
- ``constant``: ``ConstantMaterial``, one albedo, specular and roughness for the surface.
- ``model``: ``MeshColorMaterial``, constants per material or mesh colors.
- ``factory``: the one place a model is chosen (``--material``, or the kind a save stores).
- ``labels``: material masks checked before any work, clustering, per-face majority vote.
- ``stages``: the optimisation stages (constants, textured diffuse with highlight masking and
  the environment brightness factor, textured specular).
- ``schedule``: ``MaterialSchedule`` (which stage runs next) and ``run_cycle``.
- ``export``: baked texture atlas and ``write_glb`` (glTF 2.0 with KHR_materials_specular).

- ``driver``: ``MaterialDriver``, the four calls the reconstruction loop makes.

Typical use by the loop (see ``driver``)::

    driver = MaterialDriver(capture, n_materials)              # bad material masks -> InputError
    material = driver.material(mesh, cameras, images, masks)    # what Appearance.initial_material returns
    renderer = SceneRenderer(mesh, material.field, ...)         # the level's renderer (AD integrator)
    while not driver.done:                                      # alternating with geometry levels
        ...geometry level...; material.on_subdivide(old, new) or material.on_remesh(new, old, reset=False)
        driver.on_remesh(new, material, cameras, reset=False)   # only after a re-mesh
        driver.cycle(renderer, images, masks, material)
    export.write_glb(run / "result.glb", mesh, material)
"""
