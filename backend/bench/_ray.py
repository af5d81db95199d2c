"""``bench sweep --ray [ADDRESS]``: the sweep's runs as Ray tasks.

Each (scene, setting) is one task declaring ``--cpus-per-run`` CPUs (``num_cpus``), so Ray
runs as many at once as the cluster's CPUs allow; each task runs ``sweep.measure`` (the same
``reconstruct`` child process, scores and row as a local sweep) and returns its row, which the
driver appends to the one ``results.jsonl`` as the tasks finish. Scenes are synthesised on the
driver first, into ``--out``: on a cluster of several machines that folder must be shared (the
same path on every node). Without ADDRESS a local Ray instance is started (or the one already
initialised in this process is used).

Ray is optional: it is not in backend/requirements.txt nor in the extension (``pip install ray``);
the repository's requirements.txt installs it for the test of this path."""

from __future__ import annotations

import pickle
from pathlib import Path

from .. import variant as variants
from ..errors import InputError
from ._machine import REPO

LOCAL = "local"


def require_ray():
    """The ray module, or InputError (exit 2, one line) when it is not installed."""
    try:
        import ray  # here: Ray is optional; only --ray needs it
    except ImportError:
        raise InputError(None, "--ray needs Ray, which is not installed",
                         "pip install ray (into the backend's Python), or leave out --ray to run locally") from None
    return ray


def _measure(job: bytes, scene: str, capture: str, out: str, repeats: int, repeat_under: float, variant,
             eval_spp: int, seed: int) -> dict:
    """One sweep run inside a Ray worker (module level: workers import it by name): ``job`` is
    the pickled (sweep.measure, Setting), unpickled once the worker has chosen the variant, as
    importing sweep loads the renderers (and this module does not import sweep)."""
    variants.choose(variant)  # the worker's process boundary: it scores the result with Mitsuba
    measure, setting = pickle.loads(job)
    return measure(scene, Path(capture), setting, Path(out), repeats, repeat_under, variant, eval_spp, seed)


def run_tasks(ray, measure, todo: list[tuple[str, Path, object]], args, on_row) -> None:
    """Run ``measure`` (sweep.measure) for every (scene, capture folder, Setting) of ``todo`` as
    a task; ``on_row(i, scene, setting, row)`` as each finishes (in the order they finish)."""
    if not ray.is_initialized():
        address = None if args.ray == LOCAL else args.ray
        ray.init(address=address, include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": {"PYTHONPATH": str(REPO)}})
    task = ray.remote(num_cpus=args.cpus_per_run)(_measure)
    pending = {task.remote(pickle.dumps((measure, setting)), scene, str(capture), str(Path(args.out).resolve()), args.repeats,
                           args.repeat_under, args.variant, args.eval_spp, args.seed): (scene, setting)
               for scene, capture, setting in todo}
    done = 0
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            scene, setting = pending.pop(ref)
            done += 1
            on_row(done, scene, setting, ray.get(ref))
