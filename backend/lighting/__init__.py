"""Lighting. A captured environment map aligned with the frames (``align``, with ``response``
and ``transport``); the lighting fitted with the material (``base``: the interface,
``estimated_map``: an environment map, ``flash``: a flash at every camera, ``light_factor``: a
captured map's brightness, ``convention``: their albedo x light scale); ``modes``: which one a
run uses (``--lighting``); ``fitted``: a run's fitted lighting, read back for other views."""
