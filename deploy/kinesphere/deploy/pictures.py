"""Pictures of a demo run: every robot's final pose side by side, and joint trajectories.

Poses are rendered off-screen by MuJoCo (``MUJOCO_GL=egl`` on a headless machine) from the
q each robot last reported, so the picture shows what the robots did, not what was asked.
Sheets and plots are laid out by matplotlib (Agg, no display needed).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only: never look for a display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from kinesphere.protocol import RobotState  # noqa: E402

log = logging.getLogger(__name__)
logging.getLogger("OpenGL").setLevel(logging.WARNING)  # MuJoCo's renderer imports PyOpenGL

TILE = 360
MARGIN = 1.35
"""Camera distance relative to the ECL's tight framing of the pose."""
MAX_LEGEND = 10
DPI = 100


def _qpos(pm: Any, state: RobotState) -> np.ndarray:
    """The model configuration of a reported state: its joints and its base pose."""
    from kinesphere.platforms.mjcf import BASE_JOINTS

    q: np.ndarray = pm.neutral_qpos()
    for name, value in zip(state.joint_names, state.q, strict=True):
        if name in pm.qpos_index:
            q[pm.qpos_index[name]] = value
    for name, value in zip(BASE_JOINTS, state.base_pose, strict=False):
        if name in pm.qpos_index:
            q[pm.qpos_index[name]] = value
    return q


def render_poses(states: Sequence[RobotState], size: int = TILE) -> list[np.ndarray]:
    """Render states of one platform (its joints and base pose) with MuJoCo, one camera.

    Uses the ECL's camera (the look of its contact sheets), framed on the robot as if at the
    origin and then moved with its base; falls back to a plain free camera where that module
    is not available. A software GL context costs about a frame: one camera per robot.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    from kinesphere.platforms.mjcf import BASE_JOINTS, platform_model

    if not states:
        return []
    pm = platform_model(states[0].platform)
    try:
        from kinesphere.services.ecl.render import Camera, CameraView, frame
    except ImportError as exc:
        log.info("ECL camera not available (%s): plain camera", exc)
        return [_render_plain(pm, _qpos(pm, st), size) for st in states]
    images: list[np.ndarray] = []
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
                cam = Camera(pm, size, size, CameraView(v.lookat, v.distance))
            cam.cam.lookat[:] = (v.lookat[0] + st.base_pose[0], v.lookat[1] + st.base_pose[1],
                                 v.lookat[2])
            cam.cam.distance = MARGIN * v.distance  # room for the arm to move in peak poses
            images.append(np.asarray(cam.shoot(qpos)))
    finally:
        if cam is not None:
            cam.close()
    return images


def _render_plain(pm: Any, qpos: np.ndarray, size: int) -> np.ndarray:
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
    return np.asarray(pixels)


def _robot_bounds(m: Any, d: Any) -> tuple[np.ndarray, float]:
    """Centre and size of the robot's geoms (the floor plane excluded), to frame the camera."""
    import mujoco

    keep = m.geom_type != mujoco.mjtGeom.mjGEOM_PLANE
    if not keep.any():
        return np.asarray(m.stat.center), float(m.stat.extent)
    pos, r = d.geom_xpos[keep], m.geom_rbound[keep][:, None]
    lo, hi = (pos - r).min(axis=0), (pos + r).max(axis=0)
    return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)), 0.3)


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        fig.savefig(path, dpi=DPI, facecolor="white")
    finally:
        plt.close(fig)
    return path


def pose_sheets(sheets: dict[Path, dict[str, RobotState]], size: int = TILE) -> list[Path]:
    """Write each sheet: one tile per robot (sorted by id), captioned with id and status."""
    ids = sorted({rid for states in sheets.values() for rid in states})
    images: dict[tuple[Path, str], np.ndarray | str] = {}
    for rid in ids:
        wanted = [(path, states[rid]) for path, states in sheets.items() if rid in states]
        shots: list[np.ndarray | str]
        try:
            shots = list(render_poses([st for _, st in wanted], size))
        except Exception as exc:  # no GL here: still write the pictures, say why
            log.warning("cannot render %s: %s", rid, exc)
            shots = [f"no render: {exc}"[:60]] * len(wanted)
        for (path, _), img in zip(wanted, shots, strict=True):
            images[path, rid] = img
    for path, states in sheets.items():
        if not states:
            raise ValueError(f"no robot states to draw in {path}")
        rids = sorted(states)
        fig, axes = plt.subplots(1, len(rids), squeeze=False,
                                 figsize=(size * len(rids) / DPI, (size + 48) / DPI))
        for ax, rid in zip(axes[0], rids, strict=True):
            st, img = states[rid], images[path, rid]
            ax.set_axis_off()
            if isinstance(img, str):
                ax.text(0.5, 0.5, img, ha="center", va="center", wrap=True)
            else:
                ax.imshow(img)
            ax.text(0.02, -0.02, f"{rid} ({st.platform})\n{st.status}: {st.detail}"[:96],
                    fontsize=9, ha="left", va="top", transform=ax.transAxes)
        fig.subplots_adjust(left=0, right=1, top=1, bottom=48 / (size + 48), wspace=0.02)
        _save(fig, path)
    return list(sheets)


def final_poses_png(states: dict[str, RobotState], path: Path, size: int = TILE) -> Path:
    """One sheet of every robot's pose, side by side."""
    return pose_sheets({path: states}, size)[0]


def trajectory_png(
    robot_id: str,
    names: Sequence[str],
    times: Sequence[float],
    qs: Sequence[Sequence[float]],
    path: Path,
    width: int = 960,
    height: int = 540,
) -> Path:
    """Joint positions against time: the joints that moved most are coloured and named in the
    legend (at most MAX_LEGEND), the others drawn in grey."""
    q = np.asarray(qs, dtype=float).reshape(len(times), len(names))
    t = np.asarray(times, dtype=float)
    fig, ax = plt.subplots(figsize=(width / DPI, height / DPI))
    ax.set_title(f"{robot_id}: joint positions", loc="left")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position (rad or m)")
    ax.grid(True, color="0.9")
    if t.size == 0:
        ax.text(0.5, 0.5, "no states recorded", ha="center", va="center",
                transform=ax.transAxes)
        return _save(fig, path)
    span = q.max(axis=0) - q.min(axis=0)
    moved = [int(i) for i in np.argsort(-span) if span[i] > 1e-3][:MAX_LEGEND]
    still = [i for i in range(len(names)) if i not in moved]
    for i in still:
        ax.plot(t, q[:, i], color="0.8", linewidth=0.8)
    for i in moved:
        ax.plot(t, q[:, i], linewidth=1.6, label=names[i][:20])
    if still:
        ax.plot([], [], color="0.8", label=f"{len(still)} more (grey)")
    if moved or still:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=9)
    ax.margins(x=0)
    fig.tight_layout()
    return _save(fig, path)
