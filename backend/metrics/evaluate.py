"""Compare a reconstruction with ground truth: Chamfer-L1 and F1, albedo RMSE, PSNR/SSIM.

The library of the ``evaluate`` command (:func:`evaluate`, :func:`table`, :func:`write_report`),
also used by the benchmarks that score their runs.

The prediction is a mesh file or a run folder holding ``result.ply``. The truth is a mesh
file or a capture folder whose ``capture.json`` names ``ground_truth.mesh``. Geometry is
compared in the truth's normalised frame (:mod:`backend.metrics.geometry`); albedo RMSE is
added when both meshes carry vertex colours; PSNR/SSIM are added for ``--renders``, a folder
of predicted renders of the truth capture's held-out (or relit, ``--views relit``) views named
``<frame name>.exr`` (or ``.png``).

For a run folder the final display mesh is rendered at the truth's held-out views under the
lighting the run fitted (backend.lighting.fitted: the captured lights x its light factor, its
estimated map, or its flash) and at the relit views under their own map (a flash or estimate
run's albedo first brought from the convention's units and colour to the truth's:
``relit_albedo_scale``), and its material, carried onto the true surface, at the held-out
views (``true geometry``: the PSNR the same material reaches on perfect geometry, so the
difference is the geometry's). When the run fitted a specular lobe (its display mesh carries
a non-zero ``specular``), the truth carries its material and its held-out views their light,
the held-out views are also scored as the paper's Table 1 splits them: a diffuse-only and a
specular-only pass of both, each under its own lighting (:mod:`backend.render.passes`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .. import fsio
from ..capture.format import FILENAME
from ..capture.images import read_linear_rgb, read_mask, write_image
from ..capture.load import load_capture
from ..errors import InputError, require
from ..geometry.mesh import Mesh, load_mesh
from ..lighting import fitted
from ..material.transfer import carry_vertex_material
from ..render.fields import VertexField
from ..render.passes import component_renders
from ..render.views import display_field, render_views
from . import geometry as geo
from .image import albedo_rmse, image_metrics

RESULT = "result.ply"
RENDER_SUFFIXES = (".exr", ".hdr", ".png", ".jpg", ".jpeg")
VIEW_SETS = ("held_out", "relit")  # keys of a synthetic capture's ground_truth
# how a run with per-frame gains (--exposure) is scored at the truth's held-out views, which
# are rendered at gain 1: the gauge of the fitted gains (their geometric mean, and the true
# gains' of synth --exposure-drift)
HELD_OUT_GAIN = "gain 1: the gauge of the fitted gains (their geometric mean)"


def _mesh(path: Path, role: str) -> Mesh:
    mesh = load_mesh(path)
    fix = f"re-export the {role} mesh"
    require(mesh.n_faces > 0, path, "mesh has no faces", fix)
    require(bool(np.all(np.isfinite(mesh.vertices))), path, "mesh has NaN or Inf vertices", fix)
    require(int(mesh.faces.min()) >= 0 and int(mesh.faces.max()) < mesh.n_vertices, path,
            "mesh faces index missing vertices", fix)
    require(float(mesh.face_areas().sum()) > 0, path, "mesh has no surface area", fix)
    return mesh


def prediction_path(path: str | Path) -> Path:
    """The mesh to evaluate: the file itself or ``RUN/result.ply``."""
    path = Path(path)
    if path.is_dir():
        require((path / RESULT).is_file(), path / RESULT, "run folder has no result",
                "wait for the run to finish or give a mesh file")
        return path / RESULT
    require(path.is_file(), path, "prediction not found", "give a mesh file or a run folder")
    return path


def truth_capture(path: str | Path):
    """The capture behind ``--truth``, or None when it is a mesh file."""

    path = Path(path)
    if path.is_dir() or path.name == FILENAME:
        require((path / FILENAME).is_file() if path.is_dir() else path.is_file(),
                path / FILENAME if path.is_dir() else path, "ground-truth capture has no capture.json",
                "give a synthetic capture folder or a ground-truth mesh file")
        return load_capture(path, validate=False)
    require(path.is_file(), path, "ground truth not found", "give a mesh file or a synthetic capture folder")
    return None


def _truth_mesh_path(truth: Path, capture) -> Path:
    if capture is None:
        return truth
    rel = capture.ground_truth.get("mesh")
    require(bool(rel), capture.root / "capture.json", "capture has no ground_truth.mesh",
            "give the ground-truth mesh file with --truth")
    return capture.path(rel)


def _view_metrics(capture, renders: Path, views: str) -> dict:
    """PSNR/SSIM of the renders in ``renders`` against the truth capture's ``views`` set."""

    require(capture is not None, None, "--renders needs a ground-truth capture",
            f"give --truth a synthetic capture folder with ground_truth.{views}")
    rel = capture.ground_truth.get(views)
    require(bool(rel), capture.root / "capture.json", f"capture has no ground_truth.{views} views",
            "synthesise the capture with held-out views or leave out --renders")
    require(renders.is_dir(), renders, "renders folder not found", "give the folder of predicted renders")
    view_set = load_capture(capture.path(rel))
    predicted, targets, masks = [], [], []
    for frame in view_set.frames:
        found = [renders / f"{frame.name}{s}" for s in RENDER_SUFFIXES if (renders / f"{frame.name}{s}").is_file()]
        require(bool(found), renders / f"{frame.name}.exr", f"no render of view '{frame.name}'",
                f"render every {views} view into the renders folder")
        image = read_linear_rgb(found[0])
        target = read_linear_rgb(frame.image)
        require(image.shape == target.shape, found[0],
                f"render is {image.shape[1]}x{image.shape[0]} but the view is {target.shape[1]}x{target.shape[0]}",
                "render at the view's camera resolution")
        predicted.append(image)
        targets.append(target)
        masks.append(read_mask(frame.mask) if frame.mask is not None else None)
    if all(m is None for m in masks):
        masks = None
    elif any(m is None for m in masks):
        raise InputError(view_set.root, "only some views have masks", "give every view a mask or none")
    try:
        return dict(image_metrics(predicted, targets, masks), set=views)
    except ValueError as err:
        raise InputError(view_set.root, str(err), "check the view masks") from err


def evaluate(prediction: str | Path, truth: str | Path, samples: int = geo.DEFAULT_SAMPLES, seed: int = 0,
             align: str = "none", renders: str | Path | None = None, views: str = "held_out") -> dict:
    """All metrics that the inputs allow, as a dict (see the module docstring).

    PSNR is ``inf`` for a view rendered exactly; pass the dict through :func:`json_safe`
    before writing JSON."""
    require(samples >= 1, None, f"--samples is {samples}", "give at least 1 sample per mesh")
    pred_path = prediction_path(prediction)
    capture = truth_capture(truth)
    truth_path = _truth_mesh_path(Path(truth), capture)
    pred, gt = _mesh(pred_path, "predicted"), _mesh(truth_path, "ground-truth")
    report = {"prediction": str(pred_path), "truth": str(truth_path), "alignment": {"method": align}}
    if align == "icp":
        matrix = geo.align_by_icp(pred, gt, seed=seed)
        pred = pred.transformed(matrix)
        report["alignment"].update(matrix=matrix.tolist(), scale=float(np.cbrt(np.linalg.det(matrix[:3, :3]))))
    report["geometry"] = geo.geometry_metrics(pred, gt, samples, seed)
    if pred.vertex_colors is not None and gt.vertex_colors is not None:
        pa, ga = geo.corresponding_albedo(pred, gt, samples, seed)
        report["albedo"] = {"rmse": albedo_rmse(pa, ga), "rmse_scaled": albedo_rmse(pa, ga, fit_scale=True)}
    if renders is not None:
        report["images"] = _view_metrics(capture, Path(renders), views)
    elif (pred_path.parent / "snapshot.json").is_file() and capture is not None:
        _run_view_metrics(report, pred_path.parent, capture, gt, samples, seed)
    return report


def _run_view_metrics(report: dict, run: Path, capture, gt: Mesh, samples: int, seed: int) -> None:
    """For a run folder: render its final display mesh (which carries the material) at the
    truth's held-out views under the lighting the run fitted (backend.lighting.fitted) and at
    its relit views under their own map, into RUN/renders/<set>/, and score them and its albedo."""
    display = _mesh(run / json.loads((run / "snapshot.json").read_text())["mesh"], "display")
    if display.vertex_colors is not None and gt.vertex_colors is not None and "albedo" not in report:
        pa, ga = geo.corresponding_albedo(display, gt, samples, seed)
        report["albedo"] = {"rmse": albedo_rmse(pa, ga), "rmse_scaled": albedo_rmse(pa, ga, fit_scale=True)}
    lighting = fitted.from_run(run)
    report_path = run / "report.json"
    per_frame_gains = report_path.is_file() and bool(
        (json.loads(report_path.read_text()).get("exposure") or {}).get("gains"))
    for name in [s for s in VIEW_SETS if capture.ground_truth.get(s)]:
        truth_views = load_capture(capture.root / capture.ground_truth[name])
        shown, scale = display, None
        if name == "held_out":  # the views of the capture the run fitted: under the lighting it fitted
            views = fitted.light_views(truth_views, lighting)
        else:  # a light the run never saw: its own lights, the run's albedo in the truth's units
            views, scale = truth_views, relit_albedo_scale(display, gt, lighting, samples, seed)
            if scale is not None:  # flash/estimate: albedo x a (specular x mean a), undoing the convention
                shown = scaled_material(display, scale)
        out = run / "renders" / name
        for frame, image in render_views(shown, views).items():
            write_image(out / f"{frame}.exr", image)
        scores = report.setdefault("views", {})[name] = _view_metrics(capture, out, name)
        scores["lighting"] = lighting.describe() if name == "held_out" else "the views' own map"
        if name == "held_out" and per_frame_gains:
            scores["exposure"] = HELD_OUT_GAIN
        if lighting.convention and name != "held_out":
            scores["albedo_scale"] = scale
        lit_truth = truth_views.environment is not None or truth_views.has_point_lights  # its passes render
        if name == "held_out" and has_specular_lobe(display) and _material_of(gt) is not None and lit_truth:
            scores["components"] = _component_metrics(display, gt, views, truth_views)
        if name == "held_out":
            # the fitted material on the true surface: what the geometry alone costs in PSNR
            out = run / "renders" / "true_geometry"
            for frame, image in render_views(carry_vertex_material(display, gt), views).items():
                write_image(out / f"{frame}.exr", image)
            report["views"]["true_geometry"] = dict(_view_metrics(capture, out, name), set="true geometry",
                                                    lighting=scores["lighting"])


def relit_albedo_scale(display: Mesh, gt: Mesh, lighting, samples: int, seed: int) -> list[float] | None:
    """The factors a (one per channel) that bring a flash or estimate run's albedo (mean 0.5 by
    the convention, its colour split with the light's as the fit left it:
    backend.lighting.convention) to the truth's units and colour, so that its relit views
    compare with a captured run's: mean true over mean predicted albedo per channel at
    corresponding surface points, the free scale and colour of albedo x light. None for a
    captured run (its albedo is in the light's units already) or when either mesh has no
    albedo (the relit views are then scored unscaled)."""
    if not lighting.convention or display.vertex_colors is None or gt.vertex_colors is None:
        return None
    pa, ga = geo.corresponding_albedo(display, gt, samples, seed)
    mean = np.mean(pa, 0)
    return [round(float(g) / float(m), 6) for g, m in zip(np.mean(ga, 0), mean)] if mean.min() > 1e-6 else None


def scaled_material(mesh: Mesh, factor) -> Mesh:
    """A copy of a display mesh with albedo x ``factor`` (a scalar or one per channel) and
    specular x its mean (kept in [0, 1]), as the convention rescales them."""
    out = mesh.copy()
    f = np.asarray(factor, np.float32)
    out.vertex_colors = np.clip(mesh.vertex_colors * f, 0, 1).astype(mesh.vertex_colors.dtype)
    if "specular" in mesh.attributes:
        spec = mesh.attributes["specular"]
        out.attributes = dict(mesh.attributes, specular=np.clip(spec * f.mean(), 0, 1).astype(spec.dtype))
    return out


SPECULAR_FLOOR = 1e-4  # a display mesh whose specular stays below this has no lobe to score


def has_specular_lobe(mesh: Mesh) -> bool:
    spec = mesh.attributes.get("specular")
    return spec is not None and float(np.max(spec)) > SPECULAR_FLOOR


def _material_of(mesh: Mesh):
    """The truth's material as a field, or None when its mesh does not carry one."""
    if mesh.vertex_colors is None or not all(k in mesh.attributes for k in ("specular", "roughness")):
        return None
    return VertexField(mesh.faces, mesh.vertex_colors, mesh.attributes["specular"], mesh.attributes["roughness"])


def _component_metrics(display: Mesh, gt: Mesh, views, truth_views, spp: int = 64, max_depth: int = 4) -> dict:
    """PSNR/SSIM of the diffuse-only and specular-only passes of ``display`` (under the run's
    lighting, ``views``) against the same passes of the truth (under the capture's,
    ``truth_views``), both rendered now with the same seeds at the same frames."""
    components = ("diffuse", "specular")
    kw = dict(spp=spp, max_depth=max_depth, components=components)
    predicted = component_renders(display, display_field(display), views.frames, views.environment, **kw)
    truth = component_renders(gt, _material_of(gt), truth_views.frames, truth_views.environment, **kw)
    masks = [read_mask(f.mask) for f in views.frames] if all(f.mask is not None for f in views.frames) else None
    out = {}
    for name in components:
        scores = image_metrics(predicted[name], truth[name], masks)
        out[name] = {"psnr": scores["psnr"], "ssim": scores["ssim"]}
    return out


def json_safe(value):
    """The report with non-finite floats as the strings "inf", "-inf", "nan" (JSON has none)."""
    if isinstance(value, float) and not math.isfinite(value):
        return "inf" if value > 0 else ("-inf" if value < 0 else "nan")
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    return value


def write_report(path: str | Path, report: dict) -> None:
    """:func:`evaluate`'s report as JSON at ``path`` (non-finite floats as strings)."""
    fsio.write_json(path, json_safe(report))


def table(report: dict) -> str:
    """A compact human-readable summary of :func:`evaluate`'s report."""
    g = report["geometry"]
    rows = [("chamfer_l1", f"{g['chamfer_l1']:.5f}",
             f"accuracy {g['accuracy']:.5f}, completeness {g['completeness']:.5f}; "
             f"units of the truth's longest side ({g['truth_extent']:.4g})")]
    for key in g:
        if key.startswith("f1@"):
            tau = key[3:]
            rows.append((key, f"{g[key]:.2f} %",
                         f"precision {g['precision@' + tau]:.2f}, recall {g['recall@' + tau]:.2f}"))
    if report["alignment"].get("scale") is not None:
        rows.append(("alignment", "icp", f"scale {report['alignment']['scale']:.4g}"))
    if "albedo" in report:
        rows.append(("albedo_rmse", f"{report['albedo']['rmse']:.4f}",
                     f"{report['albedo']['rmse_scaled']:.4f} after per-channel scale"))
    for im in ([report["images"]] if "images" in report else []) + list(report.get("views", {}).values()):
        a = im.get("albedo_scale")
        scaled = f"; albedo x ({', '.join(f'{x:.3g}' for x in np.atleast_1d(a))}) (convention)" if a else ""
        rows.append((f"psnr {im['set']}", f"{im['psnr']:.2f} dB", f"{len(im['views'])} views, sRGB{scaled}"))
        rows.append((f"ssim {im['set']}", f"{im['ssim']:.4f}", ""))
        for name, scores in im.get("components", {}).items():
            rows.append((f"psnr {name}", f"{scores['psnr']:.2f} dB",
                         f"SSIM {scores['ssim']:.4f}; {name}-only pass against the truth's"))
    width = max(len(r[1]) for r in rows)
    return "\n".join(f"{name:<14} {value:>{width}}  {note}".rstrip() for name, value, note in rows)

