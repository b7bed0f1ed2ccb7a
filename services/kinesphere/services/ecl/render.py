"""Pictures of ECL poses, so a person can check a databank at a glance.

Three products: one pose, a contact sheet of a (limb, origin) pair's 27 directions laid out
like the paper's direction chart (rows high/middle/low, columns the 9 horizontals), and one
command on every platform side by side (the paper's "same command, different bodies" figure).
Every frame is a MuJoCo off-screen render (set MUJOCO_GL=egl on a headless machine) of the
pose f_SB returns, composed with Pillow. Each platform has one fixed camera, from the front
and a little to the robot's left, so cells compare and the robot's left shows on the
viewer's right, as when facing a person.
"""

from __future__ import annotations

import copy
import math
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass

if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "egl")  # MuJoCo picks its GL backend at first import

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image, ImageDraw, ImageFont  # noqa: E402

from kinesphere.closing import Closable
from kinesphere.errors import KinesphereError
from kinesphere.laban import RING, Direction, Horizontal, Level
from kinesphere.platforms.mjcf import PlatformModel, model_of, platform_model  # noqa: E402
from kinesphere.protocol import Pose
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.options import SHEET_SIZE
from kinesphere.sizes import size_name

LEVELS = (Level.HIGH, Level.MIDDLE, Level.LOW)
COLUMNS = (Horizontal.PLACE, *RING)  # place, then counter-clockwise seen from above
CONVENTION = "seen from the front-left: the robot's left is on the viewer's right"
AZIMUTH = 205.0  # degrees: camera in front (+x) and a little to the robot's left (+y)
ELEVATION = -12.0
FILL = 0.95  # fraction of the field of view the bounding box may fill
CELL = 200  # pixels per contact-sheet cell (square)
SHADOW_TEXELS_PER_PIXEL = 4
"""Shadow map texels per pixel of the picture's longer side (at least 1024, at most the
model's own 4096): a map far finer than the picture is drawn for nothing, and without a GPU
the shadow pass is most of a shot (Baxter at 96x80: 118 ms a shot with 4096, 71 with 1024;
12 of 7,680 pixels differ by more than 8 of 255)."""
LABEL = 22  # pixels of caption under each cell
TITLE = 52
BACKGROUND = (245, 246, 248)
MISSING = (214, 216, 220)
INK = (30, 32, 36)
FADED = (120, 124, 130)


@dataclass(frozen=True)
class CameraView:
    """A fixed free camera for one platform."""

    lookat: tuple[float, float, float]
    distance: float


def frame(pm: PlatformModel, configurations: Sequence[np.ndarray]) -> CameraView:
    """A camera that fits the robot in every given configuration (the neutral one too), so
    all frames of one picture share a view and compare directly."""
    model = pm.model
    data = mujoco.MjData(model)
    floor = model.geom("floor").id
    geoms = np.array([g for g in range(model.ngeom)
                      if g != floor and model.geom_rgba[g, 3] > 0], dtype=int)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for q in [pm.neutral_qpos(), *configurations]:
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        pos, radius = data.geom_xpos[geoms], model.geom_rbound[geoms][:, None]
        lo = np.minimum(lo, (pos - radius).min(axis=0))
        hi = np.maximum(hi, (pos + radius).max(axis=0))
    lo[2] = max(float(lo[2]), 0.0)  # nothing shows below the floor
    centre = (lo + hi) / 2
    az, el = math.radians(AZIMUTH), math.radians(ELEVATION)
    forward = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    fit = math.tan(math.radians(float(model.vis.global_.fovy)) / 2) * FILL
    half = (hi - lo) / 2
    distance = max(  # every corner of the box inside the square field of view
        max(abs(float(p @ right)), abs(float(p @ up))) / fit - float(p @ forward)
        for p in (half * np.array([x, y, z]) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1))
    )
    return CameraView((float(centre[0]), float(centre[1]), float(centre[2])), distance)


def pose_qpos(pm: PlatformModel, pose: Pose | None) -> np.ndarray:
    """The model configuration of a pose: neutral for joints it leaves NULL, the base moved
    by its translation (body frame = world frame at the origin) on mobile platforms."""
    q: np.ndarray = pm.neutral_qpos()
    if pose is None:
        return q
    for joint, value in pose.joints.items():
        q[pm.qpos_index[joint]] = value
    if pose.translation is not None and "base_x" in pm.qpos_index:
        q[pm.qpos_index["base_x"]] += pose.translation[0]
        q[pm.qpos_index["base_y"]] += pose.translation[1]
    return q


def _headless_gl() -> None:
    """Use EGL when there is no display, even if MuJoCo was imported before MUJOCO_GL was set
    (it then chose GLFW, which cannot open a window here and would abort the process)."""
    if not sys.platform.startswith("linux") or os.environ.get("DISPLAY"):
        return
    from mujoco.rendering.classic import gl_context

    if getattr(gl_context, "_MUJOCO_GL", "egl") in ("", "glfw", "enable", "enabled", "on",
                                                    "true", "1"):
        from mujoco.egl import GLContext

        gl_context.GLContext = GLContext
        gl_context._MUJOCO_GL = "egl"


class Camera(Closable):
    """An off-screen renderer for one platform, reused for every frame of a picture."""

    def __init__(self, pm: PlatformModel, width: int, height: int, view: CameraView) -> None:
        _headless_gl()
        self.pm = pm
        self.model = copy.deepcopy(pm.model)  # private: the cached model stays untouched
        vis = self.model.vis
        vis.global_.offwidth = max(int(vis.global_.offwidth), width)
        vis.global_.offheight = max(int(vis.global_.offheight), height)
        vis.quality.shadowsize = min(int(vis.quality.shadowsize), shadow_size(width, height))
        vis.headlight.ambient[:] = (0.35, 0.35, 0.35)
        vis.headlight.diffuse[:] = (0.55, 0.55, 0.55)
        vis.map.zfar = 500.0  # draw the floor out to the horizon
        self.data = mujoco.MjData(self.model)
        self.renderer = mujoco.Renderer(self.model, height, width)
        self.cam = mujoco.MjvCamera()
        self.cam.lookat[:] = view.lookat
        self.cam.distance = view.distance
        self.cam.azimuth = AZIMUTH
        self.cam.elevation = ELEVATION

    def shoot(self, qpos: np.ndarray) -> Image.Image:
        """Render a configuration; the empty sky becomes a light background."""
        self.data.qpos[:] = qpos
        mujoco.mj_forward(self.model, self.data)
        self.renderer.update_scene(self.data, self.cam)
        rgb = self.renderer.render().copy()
        self.renderer.enable_depth_rendering()
        self.renderer.update_scene(self.data, self.cam)
        depth = self.renderer.render()
        self.renderer.disable_depth_rendering()
        far = depth >= float(depth.max()) * (1 - 1e-6)
        sky = _sky(far)
        rgb[sky] = BACKGROUND
        rows, cols = np.nonzero(far & ~sky)  # far-away floor specks near the horizon
        rgb[rows, cols] = rgb[np.minimum(rows + 2, rgb.shape[0] - 1), cols]
        return Image.fromarray(rgb)

    def close(self) -> None:
        self.renderer.close()


def shadow_size(width: int, height: int) -> int:
    """The shadow map's side for a picture: a power of two, SHADOW_TEXELS_PER_PIXEL texels per
    pixel of its longer side, at least 1024."""
    return max(1024, 1 << (SHADOW_TEXELS_PER_PIXEL * max(width, height) - 1).bit_length())


def _sky(far: np.ndarray) -> np.ndarray:
    """Far-plane pixels connected to the top edge (flood fill by repeated dilation); specks
    of far-away floor near the horizon are not connected and are not sky."""
    sky = np.zeros_like(far)
    sky[0] = far[0]
    while True:
        grown = sky.copy()
        grown[1:] |= sky[:-1]
        grown[:-1] |= sky[1:]
        grown[:, 1:] |= sky[:, :-1]
        grown[:, :-1] |= sky[:, 1:]
        grown &= far
        if np.array_equal(grown, sky):
            return sky
        sky = grown


def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size=size)


def _caption(draw: ImageDraw.ImageDraw, box: tuple[int, int, int, int], text: str,
             size: int = 14, fill: tuple[int, int, int] = INK) -> None:
    x0, y0, x1, y1 = box
    font = _font(size)
    w = draw.textlength(text, font=font)
    draw.text((x0 + (x1 - x0 - w) / 2, y0 + (y1 - y0 - size) / 2 - 1), text, fill=fill, font=font)


def _missing(width: int, height: int, why: str = "n/a") -> Image.Image:
    img = Image.new("RGB", (width, height), MISSING)
    _caption(ImageDraw.Draw(img), (0, 0, width, height), why, size=16, fill=FADED)
    return img


def _titled(body: Image.Image, title: str, subtitle: str) -> Image.Image:
    out = Image.new("RGB", (body.width, body.height + TITLE), BACKGROUND)
    out.paste(body, (0, TITLE))
    draw = ImageDraw.Draw(out)
    draw.text((10, 6), title, fill=INK, font=_font(18))
    draw.text((10, 30), subtitle, fill=FADED, font=_font(13))
    return out


def _label(pose: Pose, pm: PlatformModel, part: str) -> str:
    alias = next((p.alias for p in pm.platform.eurdf.limbs if p.name == part), None)
    return f"{part} ({alias})" if alias else part


def pose_image(ecl: Ecl, limb: str, origin: str, direction: str, size: object,
               width: int = 640, height: int = 480) -> Image.Image:
    """One pose, titled with the command."""
    pose = ecl.query(limb, origin, direction, size)
    pm = model_of(ecl.platform)
    q = pose_qpos(pm, pose)
    with Camera(pm, width, height, frame(pm, [q])) as cam:
        picture = cam.shoot(q)
    title = (f"{ecl.platform.name}: {_label(pose, pm, pose.limb)} from {pose.origin}, "
             f"{pose.direction}, size {pose.size:g} ({size_name(pose.size)})")
    return _titled(picture, title, CONVENTION)


def contact_sheet(ecl: Ecl, limb: str, origin: str, size: object = SHEET_SIZE) -> Image.Image:
    """The 27 directions of one (limb, origin) pair at one size, as a 3x9 grid."""
    pm = model_of(ecl.platform)
    poses: dict[Direction, Pose | None] = {}
    for level in LEVELS:
        for h in COLUMNS:
            d = Direction((h.value, level.value))
            try:
                poses[d] = ecl.query(limb, origin, d, size)
            except KinesphereError as exc:
                if exc.code != "direction_unavailable":
                    raise
                poses[d] = None
    any_pose = next(p for p in poses.values() if p is not None)
    configurations = {d: pose_qpos(pm, p) for d, p in poses.items() if p is not None}
    sheet = Image.new("RGB", (CELL * len(COLUMNS), (CELL + LABEL) * len(LEVELS)), BACKGROUND)
    draw = ImageDraw.Draw(sheet)
    with Camera(pm, CELL, CELL, frame(pm, list(configurations.values()))) as cam:
        for r, level in enumerate(LEVELS):
            for c, h in enumerate(COLUMNS):
                d = Direction((h.value, level.value))
                pose = poses[d]
                x, y = c * CELL, r * (CELL + LABEL)
                shot = cam.shoot(configurations[d]) if pose else _missing(CELL, CELL)
                sheet.paste(shot, (x, y))
                _caption(draw, (x, y + CELL, x + CELL, y + CELL + LABEL), d.slug,
                         fill=INK if pose else FADED)
    shown = sum(p is not None for p in poses.values())
    title = (f"{ecl.platform.name}: {_label(any_pose, pm, any_pose.limb)} from "
             f"{any_pose.origin}, size {any_pose.size:g} ({size_name(any_pose.size)}), "
             f"{shown}/27 directions")
    return _titled(sheet, title, f"rows high/middle/low; {CONVENTION}")


def compare_sheet(limb: str, origin: str, direction: str, size: object,
                  platforms: Sequence[str], width: int = 360, height: int = 360) -> Image.Image:
    """One command on several platforms side by side; platforms that cannot answer it show
    why, greyed."""
    row = Image.new("RGB", (width * len(platforms), height + LABEL), BACKGROUND)
    draw = ImageDraw.Draw(row)
    slug = Direction.parse(direction).slug
    for i, name in enumerate(platforms):
        x = i * width
        try:
            ecl = Ecl.open(name)
            pose = ecl.query(limb, origin, direction, size)
        except KinesphereError as exc:
            row.paste(_missing(width, height, exc.code.replace("_", " ")), (x, 0))
            _caption(draw, (x, height, x + width, height + LABEL), name, fill=FADED)
            continue
        pm = platform_model(name)
        q = pose_qpos(pm, pose)
        with Camera(pm, width, height, frame(pm, [q])) as cam:
            row.paste(cam.shoot(q), (x, 0))
        _caption(draw, (x, height, x + width, height + LABEL), name)
    title = f"same command, different bodies: ({limb}, {origin}, {slug}, {size})"
    return _titled(row, title, CONVENTION)
