"""The reconstructed material: per-face material labels plus three channels (diffuse albedo,
specular reflectance, roughness), each either one constant per material or mesh colors.

This is the swappable material model the reconstruction loop drives:

    renderer = SceneRenderer(mesh, material.field, ...)   # SurfaceBSDF reads material.field
    params = material.attach(renderer.params)             # for mi.render(..., params=params)
    material.parameters() / load_parameters(...)          # latent Dr.Jit leaves by channel
    material.on_subdivide(old_mesh, new_mesh)             # exact transfer (1 -> 4 midpoint split)
    material.on_remesh(new_mesh)                          # labels carried over, values to neutral grey
    material.on_remesh(new_mesh, old_mesh, reset=False)  # ...or resampled (after simplification)
    material.display(mesh) -> Mesh                        # snapshot mesh (docs/protocol.md)
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import fsio
from ..geometry.mesh import NORMAL_ATTRIBUTES, Mesh
from .base import NEUTRAL, Material
from .field import MeshColorsField, squash_np, unsquash_np
from .meshcolors import MeshColorLayout
from .transfer import locate, project_onto_faces

@dataclass
class Channel:
    """One quantity. ``latent`` is one persistent Dr.Jit array, overwritten in place (so the
    scene parameters traversed through SurfaceBSDF keep pointing at the current values)."""

    kind: str  # "constant" (one value per material label) or "colors" (mesh colors)
    latent: mi.Float  # flat: (n_materials or n_samples) x width logits


class MeshColorMaterial(Material):
    """Diffuse albedo + GGX specular and roughness on a mesh, as constants or mesh colors."""

    KIND = "meshcolors"

    def __init__(self, mesh: Mesh, resolution: int | np.ndarray = 4, labels: np.ndarray | None = None,
                 n_materials: int | None = None, halve_resolution_on_subdivide: bool = True):
        self.vertices = mesh.vertices.copy()
        self.layout = MeshColorLayout(mesh.faces, mesh.n_vertices, resolution)
        self.halve_resolution_on_subdivide = halve_resolution_on_subdivide
        self.light_factor = 1.0
        self.labels = np.zeros(mesh.n_faces, np.int64)
        self.n_materials = 0
        self.channels = {name: Channel("constant", mi.Float(0.0)) for name in self.CHANNELS}
        self.field = MeshColorsField(self)
        self.trainable: tuple[str, ...] = tuple(self.CHANNELS)  # channels the loop may step jointly
        self._push_topology()
        self.set_labels(self.labels if labels is None else labels, n_materials)
        self.reset()

    # -- state ---------------------------------------------------------------------------
    @property
    def resolution(self) -> int:
        """The mesh colors' resolution r (the largest r_f when faces have their own)."""
        return self.layout.resolution

    @property
    def resolutions(self) -> np.ndarray:
        """(F,) each face's mesh-color resolution r_f."""
        return self.layout.resolutions

    @property
    def n_faces(self) -> int:
        return self.layout.n_faces

    def _push_topology(self) -> None:
        self.dr_table = mi.UInt32(self.layout.entries.astype(np.uint32))
        if not self.layout.uniform:  # the per-face lookup's offsets and resolutions (field.corners_mixed)
            self.dr_offsets = mi.UInt32(self.layout.offsets[:-1].astype(np.uint32))
            self.dr_resolutions = mi.Int32(self.layout.resolutions.astype(np.int32))

    def set_labels(self, labels: np.ndarray, n_materials: int | None = None) -> None:
        """Per-face material labels 0 .. n-1. Constant channels keep the values of labels that
        survive; new labels start neutral."""
        labels = np.asarray(labels, np.int64).ravel()
        if len(labels) != self.n_faces:
            raise ValueError(f"{len(labels)} labels for {self.n_faces} faces")
        n = int(n_materials or (labels.max() + 1 if len(labels) else 1))
        if labels.min(initial=0) < 0 or labels.max(initial=0) >= n:
            raise ValueError("material labels must lie in 0 .. n_materials - 1")
        old_n = self.n_materials
        self.labels, self.n_materials = labels, n
        self.dr_labels = mi.UInt32(labels.astype(np.uint32))
        for name, ch in self.channels.items():
            if ch.kind == "constant" and old_n:
                old = self.values(name)
                new = np.tile(self._neutral(name), (n, 1))
                new[:min(n, old_n)] = old[:min(n, old_n)]
                self.set_values(name, new, "constant")

    def _neutral(self, name: str) -> np.ndarray:
        return np.full(self.CHANNELS[name][0], NEUTRAL[name])

    def values(self, name: str) -> np.ndarray:
        """Current values (n, width): per material for constants, per sample for mesh colors."""
        width, lo, hi = self.CHANNELS[name]
        return squash_np(np.array(self.channels[name].latent), lo, hi).reshape(-1, width)

    def set_values(self, name: str, values: np.ndarray, kind: str | None = None) -> None:
        width, lo, hi = self.CHANNELS[name]
        kind = kind or self.channels[name].kind
        n = self.n_materials if kind == "constant" else self.layout.n_samples
        values = np.broadcast_to(np.asarray(values, np.float64).reshape(-1, width), (n, width))
        ch = self.channels[name]
        ch.kind = kind
        mi.set_property(ch.latent, mi.Float(unsquash_np(values, lo, hi).astype(np.float32).ravel()))
        dr.make_opaque(ch.latent)

    def reset(self) -> None:
        """Neutral grey constants for every material (the restart after a re-mesh)."""
        for name in self.CHANNELS:
            self.set_values(name, self._neutral(name), "constant")

    def restart_specular(self) -> None:
        for name in ("specular", "roughness"):
            self.set_values(name, NEUTRAL[name], "constant")
        self.trainable = (*self.trainable, "specular")

    def make_spatial(self, name: str) -> None:
        """Turn a constant channel into mesh colors initialised from the per-material constants."""
        if self.channels[name].kind == "colors":
            return
        const = self.values(name)
        face, _ = self.layout.sample_sites()
        self.set_values(name, const[self.labels[np.maximum(face, 0)]], "colors")

    def make_constant(self, name: str) -> None:
        """Turn mesh colors into per-material constants (area-free mean over each material's faces)."""
        if self.channels[name].kind == "constant":
            return
        per_face = self.layout.face_means(self.values(name))
        const = np.tile(self._neutral(name), (self.n_materials, 1))
        for m in range(self.n_materials):
            if np.any(self.labels == m):
                const[m] = per_face[self.labels == m].mean(0)
        self.set_values(name, const, "constant")

    def set_resolution(self, resolution: int | np.ndarray) -> None:
        """Change r (one for every face, or an (F,) array of per-face r_f), resampling mesh-color
        channels (exact where a face's new grid refines its old one)."""
        old_layout, old_values = self.layout, self._colors()
        self.layout = MeshColorLayout(old_layout.faces, old_layout.n_vertices, resolution)
        self._push_topology()
        face, bary = self.layout.sample_sites()
        face = np.maximum(face, 0)
        for name, vals in old_values.items():
            self.set_values(name, old_layout.evaluate(vals, face, bary[:, 0], bary[:, 1]), "colors")

    def _colors(self) -> dict[str, np.ndarray]:
        return {n: self.values(n) for n, ch in self.channels.items() if ch.kind == "colors"}

    # -- optimisation interface ------------------------------------------------------------
    def parameters(self) -> dict[str, mi.Float]:
        """The latent Dr.Jit leaves read by ``field``, by channel name."""
        return {name: ch.latent for name, ch in self.channels.items()}

    def load_parameters(self, params: dict) -> None:
        """Take latents back (an optimizer's updated Dr.Jit or numpy arrays) for the named channels."""
        for name, latent in params.items():
            ch = self.channels[name]
            if not dr.is_array_v(latent):
                latent = mi.Float(np.asarray(latent, np.float32).ravel())
            if dr.width(latent) != dr.width(ch.latent):
                raise ValueError(f"{name}: {dr.width(latent)} latents, expected {dr.width(ch.latent)}")
            mi.set_property(ch.latent, latent)

    def attach(self, scene_params: mi.SceneParameters) -> mi.SceneParameters:
        """Scene parameters that list the material's latents, so ``mi.render(..., params=...)``
        routes their gradients: ``scene_params`` itself when SurfaceBSDF already exposes them
        (``field.arrays()``), else a copy with them added."""
        present = {id(v) for v, *_ in scene_params.properties.values()}
        missing = {n: ch for n, ch in self.channels.items() if id(ch.latent) not in present}
        if not missing:
            return scene_params
        params = scene_params.copy()
        for name, ch in missing.items():
            params.properties[f"material.{name}"] = (ch.latent, None, None, mi.ParamFlags.Differentiable)
        return params

    # -- evaluation (numpy) ------------------------------------------------------------------
    def evaluate(self, face: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> dict[str, np.ndarray]:
        """Channel values (n, width) at surface points (face, b1, b2), as the field computes them."""
        face = np.asarray(face, np.int64)
        out = {}
        for name, ch in self.channels.items():
            vals = self.values(name)
            if ch.kind == "constant":
                out[name] = vals[self.labels[face]]
            else:
                out[name] = self.layout.evaluate(vals, face, b1, b2)
        return out

    # -- mesh changes ------------------------------------------------------------------------
    def on_subdivide(self, old_mesh: Mesh, new_mesh: Mesh) -> None:
        """Carry labels and values onto a subdivision of the old mesh (new faces lie inside old
        ones). Exact for midpoint subdivision: r is kept, or halved when even (the child grid
        then coincides with the parent grid), so the interpolated function is unchanged."""
        parent = self._parents(old_mesh, new_mesh)
        r = self.resolutions
        if self.halve_resolution_on_subdivide:
            r = np.where((r >= 2) & (r % 2 == 0), r // 2, r)
        layout = MeshColorLayout(new_mesh.faces, new_mesh.n_vertices, self._child_resolutions(r, parent))
        face, bary = layout.sample_sites()
        face = np.maximum(face, 0)
        tri = new_mesh.vertices[new_mesh.faces[face]]
        b1, b2 = bary[:, 0:1], bary[:, 1:2]
        points = (1 - b1 - b2) * tri[:, 0] + b1 * tri[:, 1] + b2 * tri[:, 2]
        old_face = parent[face]
        old_bary, _ = project_onto_faces(points, old_mesh.vertices, old_mesh.faces, old_face)
        colors = {n: self.layout.evaluate(v, old_face, old_bary[:, 1], old_bary[:, 2])
                  for n, v in self._colors().items()}
        self._replace_mesh(new_mesh, layout, self.labels[parent])
        for name, vals in colors.items():
            self.set_values(name, vals, "colors")

    def on_remesh(self, new_mesh: Mesh, old_mesh: Mesh | None = None, reset: bool = True) -> None:
        """After simplification or re-meshing: labels go to the nearest face of ``old_mesh`` (the
        mesh the material was last on, positions as the loop left them; default: the positions
        of the last transfer); values restart from neutral grey (``reset``, as the paper does) or
        are resampled at the closest old surface points. Re-vote the labels on the new mesh when
        label images are available (labels.vote_face_labels)."""
        old_vertices = self.vertices if old_mesh is None else old_mesh.vertices
        old_faces = self.layout.faces
        centroids = new_mesh.vertices[new_mesh.faces].mean(1)
        parent, _, _ = locate(centroids, old_vertices, old_faces, exhaustive=False)
        layout = MeshColorLayout(new_mesh.faces, new_mesh.n_vertices,
                                 self._child_resolutions(self.resolutions, parent))
        colors = {}
        if not reset:
            points = layout.sample_positions(new_mesh.vertices)
            f, b, _ = locate(points, old_vertices, old_faces, exhaustive=False)
            colors = {n: self.layout.evaluate(v, f, b[:, 1], b[:, 2]) for n, v in self._colors().items()}
        self._replace_mesh(new_mesh, layout, self.labels[parent])
        if reset:
            self.reset()
        for name, vals in colors.items():
            self.set_values(name, vals, "colors")

    def _child_resolutions(self, resolutions: np.ndarray, parent: np.ndarray):
        """A new mesh's resolution: one r when every face had it, else each face its parent's."""
        return int(resolutions[0]) if self.layout.uniform and len(resolutions) else resolutions[parent]

    def _parents(self, old_mesh: Mesh, new_mesh: Mesh) -> np.ndarray:
        if old_mesh.n_faces != self.n_faces:
            raise ValueError(f"the material has {self.n_faces} faces, the old mesh {old_mesh.n_faces}")
        centroids = new_mesh.vertices[new_mesh.faces].mean(1)
        parent, _, _ = locate(centroids, old_mesh.vertices, old_mesh.faces)
        return parent

    def _replace_mesh(self, mesh: Mesh, layout: MeshColorLayout, labels: np.ndarray) -> None:
        consts = {n: self.values(n) for n, ch in self.channels.items() if ch.kind == "constant"}
        self.vertices = mesh.vertices.copy()
        self.layout = layout
        self._push_topology()
        self.labels = np.asarray(labels, np.int64)
        self.dr_labels = mi.UInt32(self.labels.astype(np.uint32))
        for name, vals in consts.items():
            self.set_values(name, vals, "constant")

    # -- display ------------------------------------------------------------------------------
    def display(self, mesh: Mesh) -> Mesh:
        """The snapshot mesh: each face split r_f x r_f so vertices sit on the mesh-color samples,
        with vertex_colors = albedo and attributes specular, roughness and nx, ny, nz: the
        base mesh's vertex normals interpolated (Phong), so the flat split faces shade as the
        smooth surface that was fitted (docs/protocol.md).

        Vertices are shared where the material is continuous and split where it is not
        (material-label boundaries of constant channels; every face at r = 0)."""
        if mesh.n_faces != self.n_faces:
            raise ValueError(f"the material has {self.n_faces} faces, the mesh {mesh.n_faces}")
        spatial = any(ch.kind == "colors" for ch in self.channels.values())
        split = self.n_materials > 1 and any(ch.kind == "constant" for ch in self.channels.values())
        layout = self.layout if spatial else MeshColorLayout(self.layout.faces, self.layout.n_vertices, 1)
        F = self.n_faces
        if layout.uniform and layout.resolution == 0:  # every face: its own three vertices, the face's value
            faces = np.arange(3 * F).reshape(F, 3)
            site_face = np.repeat(np.arange(F), 3)
            site = np.tile([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], (F, 1))
            value_site = np.full_like(site, 1.0 / 3.0)
        else:
            key = layout.entries * self.n_materials + self.labels[layout.entry_face] if split else layout.entries
            _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
            faces = inverse.ravel()[layout.sub_triangle_entries()]
            site_face = layout.entry_face[first]
            site = value_site = layout.entry_barycentrics()[first]
        corners = mesh.faces[site_face]
        weights = np.stack([1 - site[:, 0] - site[:, 1], site[:, 0], site[:, 1]], -1)[..., None]
        vertices = (mesh.vertices[corners] * weights).sum(1)
        normals = (mesh.vertex_normals()[corners] * weights).sum(1)
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
        vals = self.evaluate(site_face, value_site[:, 0], value_site[:, 1])
        return Mesh(vertices, faces, vals["albedo"].astype(np.float32),
                    {"specular": vals["specular"][:, 0].astype(np.float32),
                     "roughness": vals["roughness"][:, 0].astype(np.float32),
                     **dict(zip(NORMAL_ATTRIBUTES, normals.T.astype(np.float32)))})

    # -- persistence ------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write the material state (npz, atomic) for --resume."""
        arrays = {"kind": np.array(self.KIND), "faces": self.layout.faces, "vertices": self.vertices, "labels": self.labels,
                  "resolution": np.array(self.resolution), "resolutions": self.resolutions, "n_materials": np.array(self.n_materials),
                  "light_factor": np.array(self.light_factor)}
        for name, ch in self.channels.items():
            arrays[f"{ch.kind}:{name}"] = self.values(name)
        buf = io.BytesIO()
        np.savez(buf, **arrays)  # uncompressed: written with every snapshot, zlib cost ~0.3 s at 30k faces
        fsio.write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> "MeshColorMaterial":
        data = np.load(path)
        mesh = Mesh(data["vertices"], data["faces"])
        resolution = data["resolutions"] if "resolutions" in data.files else int(data["resolution"])
        material = cls(mesh, resolution, data["labels"], int(data["n_materials"]))
        material.light_factor = float(data["light_factor"])
        for key in data.files:
            if ":" in key:
                kind, name = key.split(":")
                material.set_values(name, data[key], kind)
        return material

    def summary(self) -> dict:
        """Per-material constants (or means of mesh colors) for reports."""
        out = {"resolution": self.resolution, "materials": self.n_materials, "light_factor": self.light_factor,
               "channels": {n: ch.kind for n, ch in self.channels.items()}}
        if not self.layout.uniform:
            r = self.resolutions
            out["resolutions"] = {"min": int(r.min()), "median": float(np.median(r)), "max": int(r.max()),
                                  "samples": int(self.layout.n_samples)}
        for name, ch in self.channels.items():
            vals = self.values(name)
            if ch.kind == "colors":
                per_face = self.layout.face_means(vals)
                vals = np.array([per_face[self.labels == m].mean(0) if np.any(self.labels == m)
                                 else np.full(vals.shape[1], np.nan) for m in range(self.n_materials)])
            out[name] = np.round(vals, 4).tolist()
        return out
