"""Which lighting a reconstruction uses (``reconstruct --lighting``), resolved before any work.

- ``captured``: the capture's own lights (its environment map, its point lights) or the map
  ``--env`` gives; a capture lit by nothing stops with a one-line error (exit 2).
- ``estimate``: the environment is fitted with the material (backend.lighting.estimated_map);
  a captured map is withheld (point lights stay).
- ``rig``: the same fitted map, fixed to each view's camera instead of the world (lamps on
  the camera rig, DTU-like studios: the light turns with the view).
- ``world+rig``: a world-fixed and a camera-fixed map summed, fitted together
  (backend.lighting.summed_map): a room's light plus lamps on the camera rig.
- ``flash``: a point light at every camera centre, its intensity fitted with the material
  (backend.lighting.flash); the capture's own lights are replaced (placed here at the
  nominal intensity 1 until the run's initial estimate) and a captured map is withheld.
- ``auto``: one of ``estimate``, ``rig``, ``world+rig``, ``flash`` (and ``captured`` when the capture records a
  light), chosen by its held-out loss on a short probe on the initial mesh
  (backend.planning.lighting_choice); the capture is left as it is until the run resolves the
  winner with :func:`resolve_lighting`. The default when the capture has no light and no
  ``--env`` is given; a capture that records its lights or map (a rendered one) keeps
  ``captured``, which it knows exactly.
- ``none``: no estimate; as ``captured``, a capture without light is an error."""

from __future__ import annotations

import math
from pathlib import Path

from ..capture.model import Capture, Environment
from ..capture.validate import validate_environment
from ..errors import InputError, require
from . import flash

MODES = ("auto", "captured", "estimate", "rig", "world+rig", "flash", "none")
# the modes that fit an environment map with the material, and the frame it is fixed to
MAP_FRAME = {"estimate": "world", "rig": "camera", "world+rig": "world+camera"}
ESTIMATED = tuple(MAP_FRAME)
HELP = ("the lighting: 'auto' (the model with the lowest held-out loss on a short probe on the initial mesh, "
        "among a world-fixed map, a camera-fixed map, the two summed, a flash at the camera and the captured "
        "lights when the capture records any; report.json lighting_choice), 'captured' (the capture's environment map and point lights, or --env), 'estimate' (an "
        "environment map fitted with the material, written as RUN/environment.exr; a captured map is withheld), "
        "'rig' (the same map fixed to the camera: lamps on the camera rig, as in DTU-like studios), "
        "'world+rig' (a world-fixed and a camera-fixed map summed, fitted together: the room's light plus the rig's; "
        "written as RUN/environment.exr and RUN/environment_rig.exr), "
        "'flash' (a point light at every camera, e.g. a phone's flash, its intensity fitted with the material; "
        "the capture's own lights are replaced) or 'none' (no estimate: a capture without light is an error). "
        "Default: auto when the capture has no light and no --env is given, else captured")


def default_mode(has_light: bool, env: str | None) -> str:
    """``captured`` when the capture has a light or ``--env`` gives one, else ``auto``."""
    return "captured" if has_light or env is not None else "auto"


def resolve_lighting(capture: Capture | None, mode: str | None, env: str | None = None,
                     strength: float | None = None, rotation: float | None = None, source=None,
                     video_light: bool = False) -> str:
    """The lighting mode of a run, with ``capture`` relit or its map withheld in place.

    ``capture`` is None for a video (its capture is written later; ``video_light`` says
    whether the video's inputs give a map). Raises InputError (exit 2) on a capture that
    nothing lights, unless the lighting is estimated."""
    require(mode is None or mode in MODES, None, f"unknown --lighting {mode}", f"give one of {', '.join(MODES)}")
    has_light = video_light if capture is None else (capture.environment is not None or capture.has_point_lights)
    mode = mode or default_mode(has_light, env)
    if mode == "auto":
        require(env is None, None, "--env gives the lighting and --lighting auto chooses it: give one of them",
                "drop --env to choose the lighting by the probe, or --lighting auto to use the map")
        require(strength is None, None, "--env-strength needs --env", "drop --env-strength")
        return mode
    if mode in ESTIMATED:
        require(env is None, None, f"--env gives the lighting and --lighting {mode} fits it: give one of them",
                f"drop --env to estimate the lighting, or --lighting {mode} to use the map")
        require(strength is None, None, "--env-strength needs --env", "drop --env-strength")
        if capture is not None:
            capture.environment = None  # withheld: the map is fitted
        return mode
    if mode == "flash":
        require(env is None, None, "--env lights the capture by a map and --lighting flash by a flash at the "
                "camera: give one of them", "drop --env to fit a camera flash, or drop --lighting flash to use the map")
        require(strength is None, None, "--env-strength needs --env", "drop --env-strength")
        if capture is not None:
            capture.environment = None  # withheld: the flash is the only light
            flash.place(capture, 1.0)
        return mode
    if capture is not None:
        relight(capture, env, strength, rotation)
        require_light(capture, source)
    elif not video_light:
        require_light(None, source)
    return mode


def relight(capture: Capture, env: str | None, strength: float | None = None, rotation: float | None = None) -> Capture:
    """The capture lit by the map ``env`` (strength and rotation as given), replacing its own."""
    if env is None:
        require(strength is None, None, "--env-strength needs --env", "give --env HDR as well")
        return capture
    strength = 1.0 if strength is None else strength
    require(math.isfinite(strength) and strength > 0, None, f"--env-strength must be above 0 (got {strength})",
            "give the map's strength, e.g. 1")
    capture.environment = Environment(Path(env).resolve(), strength, rotation or 0.0)
    validate_environment(capture)
    return capture


def require_light(capture: Capture | None, source) -> None:
    """A capture lit by nothing renders black and learns nothing: stop before any work."""
    lit = capture is not None and (capture.environment is not None or capture.has_point_lights)
    if not lit:
        raise InputError(source, "the capture has no light source (no environment map, no point lights)",
                         "give the HDR map of the lighting with --env HDR (in Blender: Import Environment Map), "
                         "or estimate it with --lighting estimate")
