"""Pictures of a demo run: every robot's final pose side by side, and joint trajectories.

Poses are rendered off-screen by MuJoCo (``MUJOCO_GL=egl`` on a headless machine) from the
q each robot last reported, so the picture shows what the robots did, not what was asked.
Plots are drawn with Pillow (already a dependency of the stack), not matplotlib.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from kinesphere.protocol import RobotState

log = logging.getLogger(__name__)
logging.getLogger("OpenGL").setLevel(logging.WARNING)  # MuJoCo's renderer imports PyOpenGL

TILE = 360
MARGIN = 1.35
"""Camera distance relative to the ECL's tight framing of the pose."""
PALETTE = [
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
]
MAX_LEGEND = 10


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow without FreeType sizing
        return ImageFont.load_default()


def _qpos(pm: Any, state: RobotState) -> np.ndarray:
    """The model configuration of a reported state: its joints and its base pose."""
    from kinesphere.robots.mjcf import BASE_JOINTS

    q: np.ndarray = pm.neutral_qpos()
    for name, value in zip(state.joint_names, state.q, strict=True):
        if name in pm.qpos_index:
            q[pm.qpos_index[name]] = value
    for name, value in zip(BASE_JOINTS, state.base_pose, strict=False):
        if name in pm.qpos_index:
            q[pm.qpos_index[name]] = value
    return q


def render_poses(states: Sequence[RobotState], size: int = TILE) -> list[Image.Image]:
    """Render states of one platform (its joints and base pose) with MuJoCo, one camera.

    Uses the ECL's camera (the look of its contact sheets), framed on the robot as if at the
    origin and then moved with its base; falls back to a plain free camera where that module
    is not available. A software GL context costs about a frame: one camera per robot.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    from kinesphere.robots.mjcf import BASE_JOINTS, platform_model

    if not states:
        return []
    pm = platform_model(states[0].platform)
    try:
        from kinesphere.services.ecl.render import Camera, View, frame
    except ImportError as exc:
        log.info("ECL camera not available (%s): plain camera", exc)
        return [_render_plain(pm, _qpos(pm, st), size) for st in states]
    images: list[Image.Image] = []
    cam = None
    try:
        for st in states:
            qpos = _qpos(pm, st)
            at_origin = qpos.copy()
            for name in BASE_JOINTS:
                if name in pm.qpos_index:
                    at_origin[pm.qpos_index[name]] = 0.0
            v = frame(pm, [at_origin])
            if cam is None:
                cam = Camera(pm, size, size, View(v.lookat, v.distance))
            cam.cam.lookat[:] = (v.lookat[0] + st.base_pose[0], v.lookat[1] + st.base_pose[1],
                                 v.lookat[2])
            cam.cam.distance = MARGIN * v.distance  # room for the arm to move in peak poses
            images.append(cam.shoot(qpos))
    finally:
        if cam is not None:
            cam.close()
    return images


def _render_plain(pm: Any, qpos: np.ndarray, size: int) -> Image.Image:
    import mujoco

    data = mujoco.MjData(pm.model)
    data.qpos[:] = qpos
    mujoco.mj_forward(pm.model, data)
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    centre, extent = _robot_bounds(pm.model, data)
    cam.lookat[:] = centre
    cam.distance = 1.4 * extent
    cam.azimuth, cam.elevation = 150.0, -20.0
    renderer = mujoco.Renderer(pm.model, size, size)
    try:
        renderer.update_scene(data, camera=cam)
        renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False  # shadow acne on floors
        pixels = renderer.render()
    finally:
        renderer.close()
    return Image.fromarray(np.asarray(pixels))


def _robot_bounds(m: Any, d: Any) -> tuple[np.ndarray, float]:
    """Centre and size of the robot's geoms (the floor plane excluded), to frame the camera."""
    import mujoco

    keep = m.geom_type != mujoco.mjtGeom.mjGEOM_PLANE
    if not keep.any():
        return np.asarray(m.stat.center), float(m.stat.extent)
    pos, r = d.geom_xpos[keep], m.geom_rbound[keep][:, None]
    lo, hi = (pos - r).min(axis=0), (pos + r).max(axis=0)
    return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)), 0.3)


def _caption(img: Image.Image, lines: Sequence[str]) -> Image.Image:
    font = _font(14)
    out = Image.new("RGB", (img.width, img.height + 20 * len(lines) + 8), "white")
    out.paste(img, (0, 0))
    draw = ImageDraw.Draw(out)
    for i, text in enumerate(lines):
        draw.text((6, img.height + 4 + 20 * i), text, fill="black", font=font)
    return out


def pose_sheets(sheets: dict[Path, dict[str, RobotState]], size: int = TILE) -> list[Path]:
    """Write each sheet: one tile per robot (sorted by id), captioned with id and status."""
    ids = sorted({rid for states in sheets.values() for rid in states})
    images: dict[tuple[Path, str], Image.Image] = {}
    for rid in ids:
        wanted = [(path, states[rid]) for path, states in sheets.items() if rid in states]
        try:
            shots = render_poses([st for _, st in wanted], size)
        except Exception as exc:  # no GL here: still write the pictures, say why
            log.warning("cannot render %s: %s", rid, exc)
            blank = Image.new("RGB", (size, size), (235, 235, 235))
            ImageDraw.Draw(blank).text((10, size // 2), f"no render: {exc}"[:60], fill="black")
            shots = [blank] * len(wanted)
        for (path, st), img in zip(wanted, shots, strict=True):
            images[path, rid] = _caption(
                img, [f"{rid} ({st.platform})", f"{st.status}: {st.detail}"[:48]])
    for path, states in sheets.items():
        tiles = [images[path, rid] for rid in sorted(states)]
        if not tiles:
            raise ValueError(f"no robot states to draw in {path}")
        sheet = Image.new("RGB", (sum(t.width for t in tiles), max(t.height for t in tiles)),
                          "white")
        x = 0
        for t in tiles:
            sheet.paste(t, (x, 0))
            x += t.width
        path.parent.mkdir(parents=True, exist_ok=True)
        sheet.save(path)
    return list(sheets)


def final_poses_png(states: dict[str, RobotState], path: Path, size: int = TILE) -> Path:
    """One sheet of every robot's pose, side by side."""
    return pose_sheets({path: states}, size)[0]


def _ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    if hi - lo <= 0:
        return [lo]
    raw = (hi - lo) / n
    mag = 10 ** math.floor(math.log10(raw))
    step = min((m * mag for m in (1, 2, 5, 10) if m * mag >= raw), default=raw)
    first = math.ceil(lo / step) * step
    return [first + i * step for i in range(int((hi - first) / step) + 1)]


def trajectory_png(
    robot_id: str,
    names: Sequence[str],
    times: Sequence[float],
    qs: Sequence[Sequence[float]],
    path: Path,
    width: int = 960,
    height: int = 540,
) -> Path:
    """Joint positions against time; joints that moved are coloured and named in the legend."""
    q = np.asarray(qs, dtype=float).reshape(len(times), len(names))
    t = np.asarray(times, dtype=float)
    img = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(img)
    font = _font(13)
    left, right, top, bottom = 70, width - 200, 40, height - 50
    draw.text((left, 12), f"{robot_id}: joint positions (rad or m) vs time (s)", fill="black",
              font=_font(16))
    if t.size == 0:
        draw.text((left, top + 20), "no states recorded", fill="black", font=font)
        path.parent.mkdir(parents=True, exist_ok=True)
        img.save(path)
        return path
    t0, t1 = float(t[0]), float(max(t[-1], t[0] + 1e-3))
    lo, hi = float(q.min()), float(q.max())
    if hi - lo < 1e-6:
        lo, hi = lo - 0.5, hi + 0.5
    pad = 0.05 * (hi - lo)
    lo, hi = lo - pad, hi + pad

    def px(tt: float, v: float) -> tuple[float, float]:
        return (left + (tt - t0) / (t1 - t0) * (right - left),
                bottom - (v - lo) / (hi - lo) * (bottom - top))

    draw.rectangle((left, top, right, bottom), outline="black")
    for v in _ticks(lo, hi):
        y = px(t0, v)[1]
        draw.line((left, y, right, y), fill=(230, 230, 230))
        draw.text((8, y - 7), f"{v:.2f}", fill="black", font=font)
    for tt in _ticks(t0, t1):
        x = px(tt, lo)[0]
        draw.line((x, top, x, bottom), fill=(230, 230, 230))
        draw.text((x - 8, bottom + 6), f"{tt:g}", fill="black", font=font)
    span = q.max(axis=0) - q.min(axis=0)
    moved = [i for i in np.argsort(-span) if span[i] > 1e-3][:MAX_LEGEND]
    for i in range(len(names)):
        if i in moved:
            continue
        draw.line([px(a, b) for a, b in zip(t, q[:, i], strict=True)], fill=(200, 200, 200))
    for k, i in enumerate(moved):
        colour = PALETTE[k % len(PALETTE)]
        draw.line([px(a, b) for a, b in zip(t, q[:, i], strict=True)], fill=colour, width=2)
        y = top + 18 * k
        draw.line((right + 12, y + 7, right + 32, y + 7), fill=colour, width=3)
        draw.text((right + 38, y), names[i][:20], fill="black", font=font)
    rest = len(names) - len(moved)
    if rest:
        draw.text((right + 12, top + 18 * len(moved) + 4), f"{rest} more (grey)", fill="gray",
                  font=font)
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path)
    return path
