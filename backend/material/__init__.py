"""Material reconstruction: diffuse albedo, specular reflectance and roughness on the mesh,
each one constant per material or *mesh colors* (Yuksel et al. 2010), so no UV map is needed
while the mesh keeps changing.

``base`` is the interface the loop sees (``Material``), ``constant`` and ``model`` its two
models, ``factory`` the one place a model is chosen; ``meshcolors`` (numpy) and ``field``
(Dr.Jit) hold the shared-sample layout and its differentiable lookup; ``labels`` the
material masks; ``stages`` and ``schedule`` the optimisation stages and their order;
``driver`` the four calls the reconstruction loop makes; ``export`` the baked atlas and
``write_glb``. Component (diffuse-only, specular-only) renders are :mod:`backend.render.passes`.

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
