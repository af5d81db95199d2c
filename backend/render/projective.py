"""Projective integrators whose silhouette terms cost less per backward pass.

Primarily visible silhouette (``silhouette_once``, on by default; False: the plugin's own
term): Mitsuba's ``render_primarily_visible_silhouette`` forms the boundary term as a lazy
product, (radiance difference x Jacobian / pdf) x motion, where only the motion is attached to
the vertices, so its primal image and its backward pass both evaluate the lazy factor: the
radiance difference (a foreground and a background path per silhouette sample) is traced
twice. Here

- the detached factor is evaluated once; both passes read it from memory;
- the radiance difference is traced for the samples that pass the plugin's visibility test
  alone (compacted, with their own sampler stream: an occluded or out-of-view sample
  contributes zero), not for every lane of the wavefront;
- with no vertex position differentiated (a material-only step) the term is zero and is
  not traced (the radiance difference is detached, so the material gets no gradient from it;
  the plugin's lazy term is never evaluated then, and evaluating it once must not change that).

The estimate is the plugin's in expectation (the kept samples draw their own random numbers,
so it is not the same sample for sample).

Indirect silhouette (shadows, ``sppi > 0``): Mitsuba's ``direct_projective`` /
``prb_projective`` with ``sppi > 0`` (shadow and indirect-silhouette gradients) build a guiding distribution over the boundary sample space
(an octree by default) in every backward pass, per sensor. Its construction projects
``guiding_seed_spp`` seed rays per pixel onto silhouette edges, then evaluates
``guiding_leaf_samples`` points in every octree leaf. The distribution only steers where the
boundary samples go (the estimate stays an importance-sampled one), so here it can be built
from fewer samples and kept per sensor while the mesh moves little:

- ``guiding_reuse``: build uses per sensor before a rebuild (1: Mitsuba's every pass).
- ``guiding_move``: rebuild earlier once a vertex has moved this many mean edge lengths
  since the build (0: no such check); a new connectivity always rebuilds.
- ``guiding_seed_spp`` / ``guiding_leaf_samples``: Mitsuba's ``proj_seed_spp`` and
  ``octree_extra_leaf_sample``.

Registered as ``sft_direct_projective`` and ``sft_prb_projective``; every other property is
the Mitsuba plugin's own."""

from __future__ import annotations

import time

import drjit as dr
import mitsuba as mi
import numpy as np
from mitsuba.ad.integrators.direct_projective import DirectProjectiveIntegrator
from mitsuba.ad.integrators.prb_projective import PathProjectiveIntegrator


def _mesh_state(scene: mi.Scene) -> tuple[tuple, list[np.ndarray]]:
    """(connectivity key, vertex positions) of the scene's differentiable silhouette shapes."""
    key, positions = [], []
    for shape in scene.silhouette_shapes():
        if not shape.is_mesh():
            continue
        key.append((shape.id(), shape.vertex_count(), shape.face_count()))
        positions.append(np.array(dr.detach(shape.vertex_positions_buffer())).reshape(-1, 3))
    return tuple(key), positions


def _mean_edge(scene: mi.Scene) -> float:
    lengths = []
    for shape in scene.silhouette_shapes():
        if not shape.is_mesh():
            continue
        v = np.array(dr.detach(shape.vertex_positions_buffer())).reshape(-1, 3)
        f = np.array(shape.faces_buffer()).reshape(-1, 3)
        lengths.append(np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=-1).ravel())
    return float(np.mean(np.concatenate(lengths))) if lengths else 0.0


class ReusedGuiding(mi.ad.ProjectiveDetail):
    """Mitsuba's projective helper with a per-sensor cache of the indirect guiding distribution."""

    def __init__(self, parent, reuse: int = 1, move: float = 0.0):
        super().__init__(parent)
        self.reuse = max(1, int(reuse))
        self.move = float(move)
        self.cache: dict[int, dict] = {}
        self.hold = False  # cache even when every pass rebuilds (a benchmark reads the last build)
        self.builds = 0
        self.build_seconds = 0.0  # wall time of the builds (each one ends in a sync)
        self.build_cpu_seconds = 0.0  # their CPU time, all threads of the process

    def _stale(self, entry: dict | None, key: tuple, positions: list[np.ndarray]) -> bool:
        if entry is None or entry["uses"] >= self.reuse or entry["key"] != key:
            return True
        if self.move > 0:
            moved = max((float(np.max(np.linalg.norm(p - q, axis=1))) for p, q in zip(positions, entry["positions"])
                         if len(p)), default=0.0)
            return moved > self.move * entry["edge"]
        return False

    def _build(self, scene, sensor, seed) -> None:
        """Mitsuba's own build of the guiding distribution, timed (wall and CPU seconds)."""
        start, cpu = time.perf_counter(), time.process_time()
        super().init_indirect_silhouette(scene, sensor, seed)
        dr.sync_thread()
        self.builds += 1
        self.build_seconds += time.perf_counter() - start
        self.build_cpu_seconds += time.process_time() - cpu

    def init_indirect_silhouette(self, scene, sensor, seed):
        if self.reuse == 1 and self.move <= 0 and not self.hold:
            self._build(scene, sensor, seed)
            return
        key, positions = _mesh_state(scene)
        entry = self.cache.get(id(sensor))
        if self._stale(entry, key, positions):
            self._build(scene, sensor, seed)
            # the sensor is kept so its id is not reused while the entry lives
            entry = {"distr": self.guiding_distr, "uses": 0, "key": key, "sensor": sensor,
                     "positions": positions if self.move > 0 else [],
                     "edge": _mean_edge(scene) if self.move > 0 else 0.0}
            self.cache[id(sensor)] = entry
        entry["uses"] += 1
        self.guiding_distr = entry["distr"]

    def clear(self) -> None:
        self.cache.clear()
        self.guiding_distr = None


_COMPACT_SEED = 0x2545F491  # the compacted samples' stream, apart from the plugin's own seeds


def _primary_silhouette_once(integrator, scene, sensor, sampler, spp):
    """The primarily visible silhouette term (the plugin's ``render_primarily_visible_silhouette``
    image), its radiance difference traced for the visible samples alone and evaluated once."""
    film = sensor.film()
    if not any(dr.grad_enabled(shape.vertex_positions_buffer()) for shape in scene.silhouette_shapes()
               if shape.is_mesh()):
        # no vertex is differentiated (a material-only step): the term is zero
        film.prepare(integrator.aov_names())
        return film.develop()
    with dr.suspend_grad():
        centre = sensor.world_transform() @ mi.Point3f(0)
        ss = integrator.proj_detail.sample_primarily_visible_silhouette(scene, centre, sampler.next_2d(), True)
        visible = ss.is_valid() & (ss.pdf > 0)
        # is the boundary point in view, unoccluded? (the plugin's test)
        back = mi.SilhouetteSample3f(ss)
        back.d = -back.d
        ray = back.spawn_ray()
        ray.maxt = dr.norm(centre - ray.o) * (1 - mi.math.ShadowEpsilon)
        visible &= ~scene.ray_test(ray, visible)
        it = dr.zeros(mi.Interaction3f)
        it.p = ss.p
        ds, _ = sensor.sample_direction(it, mi.Point2f(0), visible)
        visible &= ds.pdf != 0
        dr.eval(ss, ds.uv, visible)  # one kernel: the gathers below read memory, not a re-trace
        keep = dr.compress(visible)
        n = dr.width(keep)
        if n == 0:
            film.prepare(integrator.aov_names())
            return film.develop()
        ss = dr.gather(mi.SilhouetteSample3f, ss, keep)
        uv = dr.gather(mi.Point2f, ds.uv, keep)
        # a fresh stream for the kept samples (the estimate needs independent samples, not these)
        kept = sampler.clone()
        kept.seed(integrator.silhouette_seed ^ _COMPACT_SEED, n)
        wavelengths, weight = sensor.sample_wavelengths(dr.zeros(mi.SurfaceInteraction3f),
                                                        kept.next_1d() if mi.is_spectral else 0, True)
        delta, _ = integrator.sample_radiance_difference(scene, ss, 0, kept, wavelengths, mi.Bool(True))
        delta *= weight
        active = dr.any(delta != 0)
        jacobian = integrator.proj_detail.sensor_jacobian(sensor, ss)
        factor = delta * jacobian * dr.rcp(ss.pdf) * dr.rcp(mi.ScalarFloat(spp))
        dr.eval(factor, ss, active, uv, wavelengths)
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.p, si.prim_index, si.uv = ss.p, ss.prim_index, ss.uv
    # the normal motion of the silhouette point: the only factor attached to the vertices
    motion = dr.dot(ss.shape.differential_motion(si, active), ss.n)
    film.prepare(integrator.aov_names())
    block = film.create_block(normalize=True)
    block.set_coalesce(block.coalesce() and spp >= 4)
    block.put(pos=uv, wavelengths=wavelengths, value=factor * motion, weight=0, alpha=1, active=active)
    film.put_block(block)
    return film.develop()


def _configure(integrator, props) -> None:
    integrator.silhouette_once = bool(props.get("silhouette_once", True))
    integrator.proj_detail = ReusedGuiding(integrator, props.get("guiding_reuse", 1), props.get("guiding_move", 0.0))
    integrator.proj_seed_spp = props.get("guiding_seed_spp", integrator.proj_seed_spp)
    integrator.octree_extra_leaf_sample = props.get("guiding_leaf_samples", integrator.octree_extra_leaf_sample)


def _reusing(base, name: str):
    """``base`` (one of Mitsuba's projective integrators) with the guiding reuse and the primarily
    visible silhouette term traced once (``_configure``, ``_primary_silhouette_once``). A class
    factory, since Mitsuba's integrator types take a single base."""

    class Reusing(base):
        def __init__(self, props):
            super().__init__(props)
            _configure(self, props)

        def prepare(self, sensor, seed=0, spp=0, aovs=[]):
            self.silhouette_seed = seed  # the last sampler's seed (render_ad's silhouette sampler)
            return super().prepare(sensor, seed, spp, aovs)

        def render_primarily_visible_silhouette(self, scene, sensor, sampler, spp):
            if self.silhouette_once:
                return _primary_silhouette_once(self, scene, sensor, sampler, spp)
            return super().render_primarily_visible_silhouette(scene, sensor, sampler, spp)

    Reusing.__name__ = Reusing.__qualname__ = name
    return Reusing


ReusingDirectProjective = _reusing(DirectProjectiveIntegrator, "ReusingDirectProjective")
ReusingPathProjective = _reusing(PathProjectiveIntegrator, "ReusingPathProjective")


mi.register_integrator("sft_direct_projective", lambda props: ReusingDirectProjective(props))
mi.register_integrator("sft_prb_projective", lambda props: ReusingPathProjective(props))
