"""The state of a reconstruction as its events describe it (bpy-free).

:class:`RunState` folds the backend's events (docs/protocol.md) into what the panel shows:
status, stage, iteration, loss, overall fraction, ETA and the newest snapshot."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

STARTING, RUNNING, STOPPING, DONE, CANCELLED, FAILED = (
    "starting", "running", "stopping", "done", "cancelled", "failed")


@dataclass
class RunState:
    status: str = STARTING
    stage: str = ""
    level: int | None = None
    iteration: int = 0
    iterations: int = 0
    fraction: float = 0.0
    loss: float | None = None
    faces: int | None = None
    variant: str = ""
    snapshot: str | None = None  # newest snapshot mesh, relative to the run folder
    snapshots: int = 0  # snapshot events seen
    message: str = ""  # error or cancel message, or the final summary
    warnings: list[str] = field(default_factory=list)
    effects: str = ""  # the light-transport effects being simulated, from the newest `effects` event
    shadow_samples: str = ""  # what the level's shadow gradients cost, from the newest `shadow_samples` event
    smoothing: str = ""  # the vertex steps' Large Steps smoothing, from the `stiffness` event
    lighting: str = ""  # the fitted lighting (--lighting estimate/rig/flash), from the newest `lighting` event
    refined_cameras: str = ""  # how far --refine-cameras moved the cameras, from the newest `cameras` event
    lighting_choice: str = ""  # --lighting auto's winner and margin, from the `lighting_choice` event
    done: dict = field(default_factory=dict)  # the `done` event
    accuracy: list = field(default_factory=list)  # (seconds, held-out PSNR) of the `accuracy` events
    predicted: str = ""  # the held-out PSNR the `preset` event predicted, e.g. '24 ± 3 dB'
    planned_s: float | None = None  # the run's time the `preset` event promised (its plan)
    started: float = field(default_factory=time.monotonic)
    _eta_s: float | None = None
    _eta_at: float = 0.0

    def update(self, event: dict) -> None:
        kind = event.get("event")
        if kind in ("start", "stage", "progress") and self.status == STARTING:
            self.status = RUNNING
        if kind == "variant":
            self.variant = str(event.get("variant", ""))
        elif kind == "stage":
            self.stage = str(event.get("stage", ""))
            self.level = event.get("level")
            self.faces = event.get("faces", self.faces)
        elif kind == "progress":
            self.stage = str(event.get("stage", self.stage))
            self.level = event.get("level", self.level)
            self.iteration = int(event.get("iteration") or 0)
            self.iterations = int(event.get("iterations") or 0)
            self.loss = event.get("loss", self.loss)
            self.faces = event.get("faces", self.faces)
            if event.get("fraction") is not None:
                self.fraction = min(1.0, max(0.0, float(event["fraction"])))
            if event.get("eta_s") is not None:
                self._eta_s, self._eta_at = float(event["eta_s"]), time.monotonic()
        elif kind == "snapshot":
            self.snapshot = event.get("path", self.snapshot)
            self.snapshots += 1
            if event.get("loss") is not None:
                self.loss = event["loss"]
        elif kind == "effects":
            self.effects = effects_summary(event.get("enabled") or {})
            if not (event.get("enabled") or {}).get("shadows"):
                self.shadow_samples = ""
        elif kind == "shadow_samples":
            self.shadow_samples = shadow_samples_summary(event)
        elif kind == "stiffness":
            reason = str(event.get("reason", ""))
            note = (" (given)" if "given" in reason else
                    " (textured, one constant material)" if "constant material" in reason else "")
            self.smoothing = f"λ {float(event.get('lambda') or 0):g}{note}"
        elif kind == "preset":
            if event.get("predicted_minutes") is not None:
                self.planned_s = 60.0 * float(event["predicted_minutes"])
            if event.get("predicted_psnr") is not None:
                spread = event.get("psnr_spread")
                # a capture scored finer than the calibration captures: the prediction is a floor
                floor = event.get("psnr_extrapolated") == "finer"
                self.predicted = f"{float(event['predicted_psnr']):.0f}" + (
                    "+" if floor else "" if spread is None else f" \u00b1 {float(spread):.0f}") + " dB"
        elif kind == "lighting":
            self.lighting = lighting_summary(event)
        elif kind == "cameras":
            self.refined_cameras = refined_cameras_summary(event)
        elif kind == "lighting_choice":
            self.lighting_choice = lighting_choice_summary(event)
        elif kind == "accuracy":
            if event.get("psnr") is not None:
                self.accuracy.append((float(event.get("seconds") or 0.0), float(event["psnr"])))
        elif kind == "warning":
            self.warnings.append(str(event.get("message", "")))
        elif kind == "error":
            self.status, self.message = FAILED, str(event.get("message", "the backend failed"))
        elif kind == "cancelled":
            self.status, self.message = CANCELLED, "the last snapshot is kept"
        elif kind == "done":
            self.status, self.fraction, self.done = DONE, 1.0, dict(event)
            self._eta_s = 0.0

    def finish(self, returncode: int, log_tail: str = "") -> None:
        """Settle the status once the process exited (a crash emits no event)."""
        if returncode == 130 or self.status == CANCELLED:
            self.status = CANCELLED
            self.message = self.message or "the last snapshot is kept"
        elif returncode == 0 and self.status != FAILED:
            self.status = DONE
            self.fraction = 1.0
        else:
            self.status = FAILED
            if not self.message and returncode == 2 and log_tail:  # bad input: the CLI's one line
                self.message = log_tail.split(" | ")[-1].removeprefix("error: ")
            elif not self.message:  # a crash without an error event: the log tells what happened
                self.message = f"the backend exited with code {returncode}"
                self.message += f"; log: {log_tail}" if log_tail else ""
        self._eta_s, self._eta_at = 0.0, time.monotonic()

    def accuracy_text(self) -> str:
        """One line for the panel, e.g. 'Held-out PSNR 24.3 dB (+7.1 dB in 5m 10s, 12 scores;
        predicted 24 ± 3 dB)'."""
        if not self.accuracy:
            return ""
        (t0, first), (t1, last) = self.accuracy[0], self.accuracy[-1]
        predicted = f"; predicted {self.predicted}" if self.predicted else ""
        return (f"Held-out PSNR {last:.1f} dB ({last - first:+.1f} dB in {format_duration(t1 - t0)}, "
                f"{len(self.accuracy)} scores{predicted})")

    def next_level_text(self) -> str:
        """What the level a time budget cut off was expected to buy (the `done` event), or ''."""
        estimate = self.done.get("next_level") or {}
        if not estimate:
            return ""
        gain = estimate.get("psnr_gain_db")
        drop = estimate.get("validation_loss_drop")
        bought = (f"~{gain:+.1f} dB" if gain is not None else
                  f"~{100 * drop:.0f} % lower loss" if drop is not None else "more")
        return f"Next level ({estimate.get('size')} px) would have bought {bought} (extrapolated)"

    def stopping(self) -> None:
        if self.status in (STARTING, RUNNING):
            self.status = STOPPING

    @property
    def active(self) -> bool:
        return self.status in (STARTING, RUNNING, STOPPING)

    def elapsed(self, now: float | None = None) -> float:
        return (time.monotonic() if now is None else now) - self.started

    def eta(self, now: float | None = None) -> float | None:
        """Seconds left: the backend's estimate aged since it arrived, else extrapolated
        from the elapsed time and the overall fraction."""
        now = time.monotonic() if now is None else now
        if self._eta_s is not None:
            return max(0.0, self._eta_s - (now - self._eta_at))
        if self.fraction > 0.01:
            return self.elapsed(now) * (1.0 - self.fraction) / self.fraction
        return None

    def eta_text(self, now: float | None = None) -> str:
        return "ETA --" if (eta := self.eta(now)) is None else f"ETA {format_duration(eta)}"

    def plan_text(self, now: float | None = None) -> str:
        """The promise against the run as it goes, e.g. 'Planned 3m 00s; now 3m 40s in all', or ''."""
        eta = self.eta(now)
        if self.planned_s is None or eta is None:
            return ""
        return f"Planned {format_duration(self.planned_s)}; now {format_duration(self.elapsed(now) + eta)} in all"

    def headline(self) -> str:
        """One line for the panel: stage, iteration and loss."""
        if not self.active:
            return f"{self.status.capitalize()}: {self.message}" if self.message else self.status.capitalize()
        parts = [self.stage or self.status]
        if self.level is not None:
            parts[0] += f" (level {self.level})"
        if self.iterations:
            parts.append(f"it {self.iteration}/{self.iterations}")
        if self.loss is not None:
            parts.append(f"loss {self.loss:.4g}")
        return "  ".join(parts)


def effects_summary(enabled: dict) -> str:
    """One line for the panel, e.g. 'direct light, specular' or '3 bounces, shadows, diffuse only'."""
    depth = int(enabled.get("max_depth") or 2)
    parts = ["direct light" if depth <= 2 else f"{depth - 1} bounces"]
    if enabled.get("shadows"):
        parts.append("shadows")
    parts.append("specular" if enabled.get("specular", True) else "diffuse only")
    return ", ".join(parts)


def shadow_samples_summary(event: dict) -> str:
    """One line from a ``shadow_samples`` event, e.g. 'shadows: 7 samples/px, 1.8x a step'
    (predicted), or '..., 1.8x a step, measured' once the level has timed its steps at that count."""
    achieved, expected = event.get("achieved_ratio"), event.get("expected_ratio")
    if event.get("checked") and achieved is not None:
        cost = f", {float(achieved):.1f}x a step, measured"
    else:
        cost = f", {float(expected):.1f}x a step" if expected is not None else ""
    return f"shadows: {event.get('chosen')} samples/px{cost}"


def lighting_summary(event: dict) -> str:
    """One line from a ``lighting`` event, e.g. 'estimated map 32x16, fitted (diffuse)' or
    'flash, fitted again on the final surface'."""
    if event.get("model") == "flash":
        what = "flash"
    else:
        width, height = (event.get("resolution") or [0, 0])[:2]
        what = {"camera": "map on the camera rig", "world+camera": "world map + camera rig map"}.get(
            event.get("frame"), "estimated map") + f" {width}x{height}"
    when = event.get("when")
    if when == "restarted":
        return f"{what}, fitting again on the final surface"
    if when == "relit":
        return f"{what}, fitted again on the final surface"
    if when == "restored":
        return f"{what}, the fit before the final surface kept (the refit fitted the views worse)"
    if when == "fitted":
        return f"{what}, fitted ({event.get('stage')})"
    return f"{what}, {'resumed' if when == 'resumed' else 'first guess'}"


def refined_cameras_summary(event: dict) -> str:
    """One line from a ``cameras`` event (``reconstruct --refine-cameras``), e.g. 'cameras
    refined: 0.4 px (0.12°, 0.3 %)'."""
    if event.get("diverged") and not event.get("reprojection_px"):
        return "cameras: refinement diverged, the given cameras are kept"
    line = f"cameras refined: {float(event.get('reprojection_px') or 0.0):.2g} px"
    if event.get("rotation_deg") is not None and event.get("translation_pct") is not None:
        line += f" ({float(event['rotation_deg']):.2g}\u00b0, {float(event['translation_pct']):.2g} %)"
    return line
MODEL_NAMES = {"estimate": "world map", "rig": "rig map", "world+rig": "world + rig maps",
               "flash": "flash at the camera", "captured": "captured lights"}


def lighting_choice_summary(event: dict) -> str:
    """One line from a ``lighting_choice`` event (``--lighting auto``), e.g. 'lighting: rig map,
    by 1.2 dB' (the held-out margin over the runner-up), 'lighting: world + rig maps kept, 0.2 dB
    behind the world map' (a near tie left the run's provisional lighting), or 'lighting: world
    map (not probed)'."""
    winner = str(event.get("winner") or "")
    name = MODEL_NAMES.get(winner, winner)
    margin = event.get("margin_db")
    if margin is None:
        return f"lighting: {name} (not probed)"
    if event.get("kept"):  # a near tie after the first level: the run's provisional lighting stays
        best = str(event.get("runner_up") or "")
        return f"lighting: {name} kept, {-float(margin):.1f} dB behind the {MODEL_NAMES.get(best, best)}"
    return f"lighting: {name}, by {float(margin):.1f} dB" + (" (run-off)" if event.get("runoff") else "")


def cameras_summary(done: dict) -> str:
    """One line from capture-from-video's ``done`` event, e.g. '40/40 frames registered
    (0.52 px), refined by 37 silhouettes'."""
    if not done.get("total"):
        return ""
    line = f"{done.get('registered')}/{done.get('total')} frames registered"
    if done.get("reprojection_error_px") is not None:
        line += f" ({float(done['reprojection_error_px']):.2f} px)"
    silhouettes = done.get("silhouettes") or {}
    if silhouettes.get("applied"):
        line += f", refined by {silhouettes.get('frames')} silhouettes"
        if silhouettes.get("dropped"):
            line += f" (masks left out: {', '.join(map(str, silhouettes['dropped']))})"
    elif silhouettes.get("reason"):
        line += f", silhouettes not used: {silhouettes['reason']}"
    masks = done.get("masks") or {}
    if masks.get("kept") is not None:
        line += f"; {masks['kept']} masks made automatically"
        if masks.get("dropped"):
            line += f" ({masks['dropped']} frames dropped: their masks disagree or the object leaves the frame)"
    return line


def format_duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m {seconds % 60:02d}s"
    return f"{seconds // 3600}h {seconds % 3600 // 60:02d}m"
